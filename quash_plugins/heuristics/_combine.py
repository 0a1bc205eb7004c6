"""``combine`` heuristic: synonyms from one heuristic, antonyms from another."""

from __future__ import annotations

from typing import Any

from ..core.errors import ConfigError, QuashError
from ..core.interfaces import ExpansionContext, Heuristic
from ..core.types import QuerySet


def build_heuristic(spec: Any, where: str) -> Heuristic:
    """Build a heuristic from ``"name"``, ``{name, params: {...}}`` or ``{name, key: value}``."""
    from ..core import registry

    if isinstance(spec, Heuristic):
        return spec
    if isinstance(spec, str):
        name, params = spec, {}
    elif isinstance(spec, dict) and "name" in spec:
        name = str(spec["name"])
        rest = {k: v for k, v in spec.items() if k != "name"}
        if set(rest) == {"params"} and isinstance(rest["params"], dict):
            params = dict(rest["params"])
        elif "params" in rest:
            raise ConfigError(
                f"{where}: give the parameters either under 'params' or beside 'name', not both."
            )
        else:
            params = rest
    else:
        raise ConfigError(
            f"{where} must be a heuristic name or {{name: ..., params: {{...}}}}; got {spec!r}."
        )
    try:
        return registry.create("heuristics", name, **params)
    except QuashError as exc:
        raise type(exc)(f"{where}: {exc}") from None


class CombineHeuristic(Heuristic):
    """Positives from ``synonyms``' heuristic and negatives from ``antonyms``' heuristic.

    This is the paper's synonym-source x antonym-source ablation (e.g. adjectives for
    synonyms and ground truth for antonyms).

    Parameters
    ----------
    synonyms, antonyms
        Heuristic specs: a name, or ``{name: ..., params: {...}}`` (parameters may also
        sit beside ``name``).

    Examples
    --------
    >>> h = CombineHeuristic(synonyms={"name": "adjectives"}, antonyms="lexicon")
    >>> qs = h.expand("chair")
    >>> qs.positives[:2], len(qs.negatives)
    (['chair', 'new chair'], 20)
    """

    name = "combine"

    @staticmethod
    def conformance_params(tmp_path: Any) -> dict[str, Any]:
        """Parameters the conformance kit builds this heuristic with."""
        return {"synonyms": "adjectives", "antonyms": {"name": "lexicon", "n_synonyms": 0}}

    def __init__(self, synonyms: Any = None, antonyms: Any = None) -> None:
        if synonyms is None or antonyms is None:
            raise ConfigError(
                "Heuristic 'combine' needs both 'synonyms' and 'antonyms', e.g. "
                "{name: combine, synonyms: {name: adjectives}, antonyms: {name: taxonomy, "
                "params: {file: labels.yaml}}}."
            )
        self.synonyms = synonyms
        self.antonyms = antonyms
        self._syn = build_heuristic(synonyms, "combine.synonyms")
        self._ant = build_heuristic(antonyms, "combine.antonyms")

    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        syn = self._syn.expand(query, context)
        ant = self._ant.expand(query, context)
        return QuerySet(
            query,
            [query, *syn.positives],
            list(ant.negatives),
            self.provenance(context, synonyms=syn.provenance, antonyms=ant.provenance),
        )

    def params(self) -> dict[str, Any]:
        return {"synonyms": self._syn.name, "antonyms": self._ant.name}

    @property
    def prompt_templates(self) -> dict[str, Any] | None:
        """Templates asked for by either part (the synonym side wins)."""
        return getattr(self._syn, "prompt_templates", None) or getattr(
            self._ant, "prompt_templates", None
        )
