"""quash bench's plots: what each table's plot title says (captured from run_bench)."""

from __future__ import annotations

import pytest
from _bench import hashing_scene

from quash_plugins.evaluation import ablations

ENCODER = "hashing-bench-plot"


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    yield from hashing_scene(tmp_path_factory, ENCODER)


def test_a_tables_plot_says_how_many_queries_its_points_are_over(scene, tmp_path, monkeypatch):
    """The plot was titled with the table alone ('Antonyms (baseline)'): not what its dots
    and means are over. The title now says the present and absence queries it scored."""
    plotted = {}
    real = ablations.plot_precision_recall

    def spy(rows, path, title):
        plotted[path.stem] = (rows, title)
        return real(rows, path, title=title)

    monkeypatch.setattr(ablations, "plot_precision_recall", spy)
    ablations.run_bench(
        scene / "scene.npz",
        None,
        tmp_path / "b",
        tables=("antonyms",),
        encoder=ENCODER,
        overrides={"cache": False},
        queries=["wall", "floor", "chair"],
        absent=("piano",),
    )
    rows, title = plotted["antonyms"]
    n = len(rows[0]["per_query"])
    m = len(rows[0]["absence"]["per_query"])
    assert (n, m) == (3, 1)
    assert title == f"Antonyms (baseline)\n{n} queries, {m} absence query"
    assert (tmp_path / "b" / "antonyms.png").exists()
