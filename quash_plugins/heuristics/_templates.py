"""``templates`` heuristic: prompt engineering on the bare query.

Templates are applied by the pipeline, never by a heuristic: the pipeline's
``prompt_templates`` setting (``{mode: mean|all, templates: default|vlmaps|
vlmaps-or-default|list|path}``) is the
one mechanism, and it composes with every heuristic. This heuristic is shorthand: it
expands like ``none`` (or like its ``base`` heuristic) and exposes a
``prompt_templates`` attribute that the pipeline adopts when the config has no
``prompt_templates`` of its own (an explicit config setting wins).
"""

from __future__ import annotations

from typing import Any

from ..core.errors import ConfigError
from ..core.interfaces import ExpansionContext, Heuristic
from ..core.text import TEMPLATE_MODES, TemplateList, resolve_templates
from ..core.types import QuerySet


class TemplatesHeuristic(Heuristic):
    """The query alone (plus generic negatives), embedded through prompt templates.

    Parameters
    ----------
    mode
        ``"mean"``: each string becomes the normalised mean of its templated
        embeddings (the VLMaps/LSeg baseline's prompt engineering); ``"all"``: every
        templated variant is a training sample.
    templates
        ``"default"`` (the 61 shipped templates), ``"vlmaps"``, ``"vlmaps-or-default"``
        (:func:`~quash_plugins.core.text.resolve_templates`) or a list of strings with
        one ``{}``.
    templates_file
        A text file (one template a line) or YAML list; relative to the config.
    base
        Optional heuristic spec to expand with instead of ``none``.

    Examples
    --------
    >>> h = TemplatesHeuristic(mode="all", templates=["a photo of a {}.", "a {} in a room."])
    >>> h.prompt_templates["mode"], len(h.prompt_templates["templates"])
    ('all', 2)
    """

    name = "templates"

    def __init__(
        self,
        mode: str = "mean",
        templates: str | list[str] = "default",
        templates_file: str | None = None,
        base: Any = None,
    ) -> None:
        if mode not in TEMPLATE_MODES:
            raise ConfigError(
                f"Heuristic 'templates': mode must be one of {TEMPLATE_MODES}; got {mode!r}."
            )
        self.mode = mode
        self.templates = templates
        self.templates_file = templates_file
        self.base = base
        spec = templates_file if templates_file is not None else templates
        self._list, self._source = resolve_templates(spec)
        self._base = None
        if base is not None:
            from ._combine import build_heuristic

            self._base = build_heuristic(base, "templates.base")

    @property
    def prompt_templates(self) -> dict[str, Any]:
        """The pipeline setting this heuristic asks for."""
        return {"mode": self.mode, "templates": TemplateList(self._list, self._source)}

    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        if self._base is not None:
            inner = self._base.expand(query, context)
            pos, neg, extra = inner.positives, inner.negatives, {"base": inner.provenance}
        else:
            pos, neg, extra = [query], [], {}
        prov = self.provenance(
            context, prompt_templates={"mode": self.mode, "count": len(self._list)}, **extra
        )
        return QuerySet(query, pos, neg, prov)

    def params(self) -> dict[str, Any]:
        source = self.templates_file or (
            self.templates if isinstance(self.templates, str) else f"{len(self._list)} given"
        )
        return {
            "mode": self.mode,
            "templates": source,
            "count": len(self._list),
            "base": getattr(self._base, "name", None),
        }
