"""The whole conformance kit over every plugin this distribution registers: the one
line docs/plugins.md asks of a plugin package (run it with `pytest` after
`pip install -e .`)."""

from quash_plugins.testing import parametrize_with_checks


@parametrize_with_checks(dist="quash-char-ngram")
def test_conformance(check, tmp_path):
    check(tmp_path)
