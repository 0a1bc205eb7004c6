"""Logging an evaluation: per-query metrics as plots, one series per config, a summary.

:class:`EvalLogging` is the part of :class:`~quash_plugins.viewer.RerunLogger` that logs
an evaluation report beside the query results, on the same ``query`` timeline (the
logger's state is set up in ``RerunLogger.__init__``, in ``_rerun.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from ..core.palette import series_style
from ._blueprint import QUERY_SCORES
from ._display import slugify
from ._log_result import _same_query

#: How the query scores document names a metric (as the tables' columns do).
METRIC_NAMES = {"f1": "F1", "iou": "IoU", "ap": "AP", "inv_rank": "inv. rank"}

#: Per-query metrics :meth:`EvalLogging.log_evaluation` plots, one plot each.
EVAL_METRICS = ("f1", "precision", "recall", "iou", "ap")


class EvalLogging:
    """:meth:`log_eval_scalars`, :meth:`log_evaluation` and :meth:`log_summary`; a base of
    ``RerunLogger``."""

    def log_summary(self, markdown: str) -> None:
        """A static Markdown document (e.g. a comparison table) shown beside the metrics."""
        rr = self.rr
        self.recording.log(
            "summary", rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True
        )
        self._has_summary = True
        self._layout_changed()

    def log_eval_scalars(
        self, config_name: str, metrics: dict[str, Any], step_or_query: int | str
    ) -> None:
        """Log evaluation metrics as scalars under ``eval/<metric>/<config>``.

        Parameters
        ----------
        config_name
            The method config's name; one series per config and metric.
        metrics
            ``{"precision": p, "recall": r, "f1": f, "iou": i, ...}``; every finite
            number is logged, other values are skipped. Grouping by metric first gives
            one plot per metric that compares the configs.
        step_or_query
            Position on the ``query`` timeline: an int, or a query string: the step
            where :meth:`log_result` logged that query, else the first step no query is
            at yet (0, 1, 2... in order of first appearance when no result was logged);
            the same query string gets the same step for every config.
        """
        if isinstance(step_or_query, str):
            step = self._step_of(step_or_query)
        else:
            step = int(step_or_query)
        with self._at_query_step(step):
            self._log_scalars_at_step(str(config_name), metrics, step, step_or_query)
        self._layout_changed()

    def _log_scalars_at_step(
        self, config_name: str, metrics: dict[str, Any], step: int, step_or_query: int | str
    ) -> None:
        """:meth:`log_eval_scalars` once the ``query`` time is set."""
        rr, rec = self.rr, self.recording
        if isinstance(step_or_query, str):
            self._list_query(step, step_or_query, "log_eval_scalars")
        cfg = self._config_slug(str(config_name))
        shown: dict[str, float] = {}
        for key, value in metrics.items():
            try:
                v = float(value)
            except (TypeError, ValueError):
                continue
            if not math.isfinite(v):
                continue
            metric = slugify(str(key), "metric")
            path = f"eval/{metric}/{cfg}"
            if path not in self._eval_series:
                self._eval_series.add(path)
                k = self._eval_colors.setdefault(cfg, len(self._eval_colors))
                color, marker = series_style(k)  # the PNG's too (core.palette)
                name = str(config_name)
                rec.log(path, rr.SeriesLines(names=name, colors=color), static=True)
                rec.log(
                    path,
                    rr.SeriesPoints(names=name, colors=color, markers=marker, marker_sizes=3.0),
                    static=True,
                )
            rec.log(path, rr.Scalars([v]))
            self._eval_metrics.setdefault(metric, None)
            self._eval_last = max(self._eval_last, step)
            shown[metric] = v
        if shown:
            self._log_query_scores(str(config_name), cfg, step, shown)

    def _log_query_scores(
        self, config_name: str, cfg: str, step: int, metrics: dict[str, float]
    ) -> None:
        """``query_scores/<config>`` at ``step``: the query's scores in words, beside its
        query set in the config's tab (every metric logged at that step so far, and what
        :meth:`log_evaluation` adds: the label, TP, FP and FN, or an absence query's
        matched items)."""
        rr = self.rr
        docs = self.__dict__.setdefault("_query_scores", {})
        doc = docs.setdefault((cfg, step), {"metrics": {}, "counts": None})
        doc["metrics"].update(metrics)
        query = self._listed.get(step)
        head = f"**{config_name}**" + (f' on "{query}"' if query is not None else "")
        lines = [head]
        counts = doc["counts"] or {}
        if counts.get("absent"):
            lines[0] += " (absence query)"
            matched = counts.get("matched")
            if counts.get("empty"):
                lines.append(f"Matched {matched} items: **empty, as it should be**.")
            else:
                lines.append(
                    f"Matched {matched} items: **not empty** (an absent object should match "
                    "nothing)."
                )
        else:
            if counts.get("label") is not None:
                lines[0] += f" (ground truth: label `{counts['label']}`)"
            shown = [
                f"{METRIC_NAMES.get(m, m)} {v:.3f}"
                for m, v in doc["metrics"].items()
                if m != "absence"
            ]
            if shown:
                lines.append(" · ".join(shown))
            tp, fp, fn = (counts.get(k) for k in ("tp", "fp", "fn"))
            if all(isinstance(x, int) for x in (tp, fp, fn)):
                lines.append(
                    f"TP {tp} · FP {fp} · FN {fn}: {tp + fp} items matched, {tp + fn} carry "
                    "the label"
                )
        text = "\n\n".join(lines)
        self.recording.log(
            f"{QUERY_SCORES}/{cfg}", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN)
        )

    def _step_of(self, query: str) -> int:
        """The step of a query string: where a result (or an earlier call) named it, else
        the first step no query is named at."""
        if query not in self._eval_steps:
            named = [s for s, q in self._listed.items() if _same_query(q, query)]
            taken = set(self._listed) | set(self._eval_steps.values())
            self._eval_steps[query] = (
                min(named) if named else next(s for s in range(len(taken) + 1) if s not in taken)
            )
        return self._eval_steps[query]

    def log_evaluation(
        self,
        configs: Sequence[dict[str, Any]],
        queries: Sequence[str],
        summary_markdown: str | None = None,
        metrics: Sequence[str] = EVAL_METRICS,
        absent: Sequence[str] = (),
    ) -> None:
        """Log an evaluation report: per-query metrics of every config, and a summary.

        ``configs`` is the report's JSON list (``[{"name", "per_query": {query: {...}},
        "absence": {"per_query": {query: {"empty": ...}}}}]``,
        :class:`quash_plugins.evaluation.report.EvalReport`); query ``i`` of ``queries``
        goes to step ``i`` of the ``query`` timeline, and absence query ``j`` of
        ``absent`` to step ``len(queries) + j``, where :meth:`log_result` puts their
        results when they are logged in the report's order, so the plots line up with
        the queries shown in the 3D views. An absence query is plotted as ``absence``:
        1 when the config's mask is empty (within the report's tolerance), 0 when it
        matched something. The ``query_list`` names each step, also when no result was
        logged (``quash eval``); a step where another query was logged raises
        :class:`~quash_plugins.core.errors.QuashError` before anything is logged.
        """
        steps = [*queries, *absent]
        for i, q in enumerate(steps):  # a step named for another query is refused first
            self._check_step(i, q, "log_evaluation")
        with self._at_query_step():
            for i, q in enumerate(steps):
                self.recording.set_time("query", sequence=i)
                self._list_query(i, q, "log_evaluation")
        for c in configs:
            per_query = c.get("per_query") or {}
            cfg = self._config_slug(str(c["name"]))
            docs = self.__dict__.setdefault("_query_scores", {})
            for i, q in enumerate(queries):
                row = per_query.get(q)
                if row:
                    counts = {k: row.get(k) for k in ("tp", "fp", "fn")}
                    counts["label"] = row.get("label", q)
                    docs[(cfg, i)] = {"metrics": {}, "counts": counts}
                    self.log_eval_scalars(c["name"], {m: row.get(m) for m in metrics}, i)
            absence = (c.get("absence") or {}).get("per_query") or {}
            for j, q in enumerate(absent):
                row = absence.get(q)
                if row and isinstance(row.get("empty"), bool):
                    value = 1.0 if row["empty"] else 0.0
                    docs[(cfg, len(queries) + j)] = {
                        "metrics": {},
                        "counts": {
                            "absent": True,
                            "empty": row["empty"],
                            "matched": row.get("matched"),
                        },
                    }
                    self.log_eval_scalars(c["name"], {"absence": value}, len(queries) + j)
        if summary_markdown:
            self.log_summary(summary_markdown)
