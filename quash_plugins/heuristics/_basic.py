"""``none`` and ``static`` heuristics."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core.errors import ConfigError, HeuristicError, closest
from ..core.interfaces import ExpansionContext, Heuristic
from ..core.types import QuerySet


class NoneHeuristic(Heuristic):
    """No expansion: positives are the query, negatives the config's generic negatives.

    With ``label-argmax`` (``normalize_text: false, ties: earlier``) and VLMaps' prompt
    templates (``normalize: false``) this is VLMaps' ``index_map`` rule (docs/vlmaps.md).
    """

    name = "none"

    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        return QuerySet(query, [query], [], self.provenance(context))


class StaticHeuristic(Heuristic):
    """Positives and negatives for each query from a YAML file.

    The file maps each query to ``{positives: [...], negatives: [...]}``; the query itself
    is always the first positive.

    Parameters
    ----------
    file
        The YAML file.
    querysets
        The same mapping given in memory.
    """

    name = "static"

    def __init__(self, file: str | None = None, querysets: dict[str, Any] | None = None) -> None:
        self.file = file
        self.querysets = querysets
        if (file is None) == (querysets is None):
            raise ConfigError("Heuristic 'static' needs exactly one of 'file' or 'querysets'.")
        self._sets = self._load()

    def _load(self) -> dict[str, dict[str, list[str]]]:
        where = self.file or "querysets"
        data: Any = self.querysets
        lines: dict = {}
        if self.file is not None:
            from ..core.yaml_files import load_yaml

            path = Path(self.file)
            if not path.exists():
                raise ConfigError(f"Query-set file not found: {path}")
            data, lines = load_yaml(path)
        if not isinstance(data, dict):
            raise ConfigError(f"{where}: expected a mapping {{query: {{positives, negatives}}}}.")
        out = {}
        for query, entry in data.items():
            line = lines.get((query,))
            loc = f"{where}:{line}" if line else str(where)
            if not isinstance(entry, dict):
                raise ConfigError(f"{loc}: entry for {query!r} must be a mapping.")
            unknown = set(entry) - {"positives", "negatives"}
            if unknown:
                raise ConfigError(
                    f"{loc}: entry for {query!r} has unknown key(s) {sorted(unknown)}; "
                    "use 'positives' and 'negatives'."
                )
            pos = entry.get("positives") or []
            neg = entry.get("negatives") or []
            if not isinstance(pos, list) or not isinstance(neg, list):
                raise ConfigError(f"{loc}: 'positives' and 'negatives' must be lists.")
            out[" ".join(str(query).split())] = {
                "positives": [str(p) for p in pos],
                "negatives": [str(n) for n in neg],
            }
        return out

    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        entry = self._sets.get(query)
        if entry is None:
            guess = closest(query, self._sets)
            hint = f" Did you mean {guess!r}?" if guess else ""
            raise HeuristicError(
                f"Query {query!r} has no entry in {self.file or 'the static query sets'}. "
                f"Known queries: {', '.join(sorted(self._sets)) or '(none)'}.{hint}"
            )
        return QuerySet(
            query,
            [query, *entry["positives"]],
            list(entry["negatives"]),
            self.provenance(context, file=self.file),
        )

    def params(self) -> dict[str, Any]:
        return {"file": self.file}

    @classmethod
    def conformance_params(cls, tmp_path: Path) -> dict[str, Any]:
        return {"querysets": {"chair": {"positives": ["armchair"], "negatives": ["table"]}}}
