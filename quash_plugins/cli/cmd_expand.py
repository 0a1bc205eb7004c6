"""``quash expand``: show the positives and negatives a config makes of a query."""

from __future__ import annotations

import argparse

NAME = "expand"
HELP = "Expand a query into positives and negatives with a config's heuristic."
ORDER = 20


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ._config_opts import add_config_option, add_runtime_options

    p.add_argument("query", help="The query text, e.g. 'chair'.")
    add_config_option(p)
    p.add_argument(
        "--map", metavar="MAP", help="Map to give the heuristic (labels, mined negatives)."
    )
    p.add_argument(
        "--json",
        action="store_true",
        help='Print {"query", "positives", "negatives", "provenance"} as JSON.',
    )
    add_runtime_options(p)


def run(args: argparse.Namespace) -> int:
    from ..engine.pipeline import Quash
    from ._config_opts import apply_runtime_options, load_config
    from ._output import console, print_json

    cfg = apply_runtime_options(load_config(args.config), args)
    # An encoder whose weights are missing does not stop a heuristic that needs none
    # (llm): the expansion goes on, with a warning; one that needs it stops with the error.
    quash = Quash.from_config(cfg, defer_encoder_error=True)
    lmap = quash.read_map(args.map) if args.map else None
    if lmap is not None:
        _warn_if_the_map_does_not_fit(quash, lmap)
    elif cfg.map_negatives is not None:
        import logging

        # the set shown would lack the negatives quash query mines from its map
        logging.getLogger(__name__).warning(
            "map_negatives: mined from a map, and none was given: the negatives below lack "
            "them (quash query adds them). Give --map MAP to see them."
        )
    qs = quash.expand(args.query, lmap)
    if args.json:
        print_json(qs.to_dict())
        return 0
    from ._output import safe_text as escape

    out = console()
    out.print(f"[bold]query[/]: {escape(qs.query)}")
    out.print(f"[bold green]positives[/] ({len(qs.positives)}): " + escape(", ".join(qs.positives)))
    out.print(f"[bold red]negatives[/] ({len(qs.negatives)}): " + escape(", ".join(qs.negatives)))
    out.print(f"[bold]heuristic[/]: {escape(_summary(qs.provenance))}")
    out.print("[dim]provenance:[/]")
    out.print(f"[dim]{escape(_provenance_yaml(qs, out.width - 2))}[/]")
    return 0


def _warn_if_the_map_does_not_fit(quash, lmap) -> None:
    """A map whose dimension is not the encoder's: the expansion needs no embeddings of
    the map, so it goes on, but a query with this config on the map would stop here."""
    import logging

    from ..core.errors import DimensionMismatchError, QuashError

    try:
        quash.check_dimension(lmap)
    except DimensionMismatchError as exc:
        logging.getLogger(__name__).warning(
            "%s quash expand goes on (it embeds no map item), but quash query with this "
            "config on this map stops here.",
            exc,
        )
    except QuashError:  # an encoder that cannot be built: expand already said so
        pass


def _summary(prov: dict) -> str:
    """One line: the heuristic and what a reader most wants to know about this set."""
    name = str(prov.get("heuristic", "?"))
    bits = []
    if "seed" in prov:
        bits.append(f"seed {prov['seed']}")
    if "source" in prov:  # llm: server or cache
        bits.append(f"from {prov['source']}")
    params = prov.get("params") or {}
    if name == "llm":
        bits.append(f"model {params.get('model')} at {params.get('endpoint')}")
        bits.append(f"prompt {prov.get('prompt_version')}")
    if "label" in prov:
        bits.append(f"label {prov['label']!r}")
    resolved = prov.get("resolved")
    if resolved:
        bits.append(resolution_line(resolved))
    if name == "combine":
        syn, ant = prov.get("synonyms") or {}, prov.get("antonyms") or {}
        bits.append(f"synonyms by {syn.get('heuristic')}, antonyms by {ant.get('heuristic')}")
    tpl = prov.get("prompt_templates")
    if tpl:
        source = f" from {tpl['source']}" if tpl.get("source") else ""
        bits.append(f"{tpl.get('count')} prompt templates{source}, mode {tpl.get('mode')}")
    mined = prov.get("map_negatives")
    if mined:
        added = ", ".join(mined.get("added") or []) or "none"
        bits.append(f"map-mined negatives: {added}")
    return name + (f" ({'; '.join(bits)})" if bits else "")


def _provenance_yaml(qs, width: int = 100) -> str:
    import yaml

    class _Dumper(yaml.SafeDumper):
        pass

    def _list(dumper, items):
        # a list of numbers (negative_groups: one size per label) on one line, not one
        # line per label
        flow = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in items)
        return dumper.represent_sequence("tag:yaml.org,2002:seq", items, flow_style=flow)

    _Dumper.add_representer(list, _list)
    data = qs.to_dict()["provenance"]
    text = yaml.dump(
        data,
        Dumper=_Dumper,
        sort_keys=False,
        allow_unicode=True,
        width=max(40, width - 6),  # YAML may pass its width by a token
        default_flow_style=False,
    )
    return "\n".join("  " + line for line in text.rstrip().splitlines())


def resolution_line(r: dict) -> str:
    """How the taxonomy resolved a query, in one phrase.

    >>> resolution_line({"from": "bunk beds", "to": "bed", "how": "near-subclass", "via": "bunk bed"})
    "query 'bunk beds' resolved to label 'bed' (near match of sub-class 'bunk bed')"
    """
    how = r.get("how", "embedding")
    if how == "unlisted":
        return (
            f"query {r['from']!r} names an object that is not in the label list: kept as its "
            "own concept, not resolved to the nearest label"
        )
    if r.get("to") is None:
        return (
            f"query {r['from']!r} matches no label (nearest name {r.get('via')!r}"
            f"{_of_label(r)}, cosine {r.get('cosine')}{_under(r)}{_next(r)}): kept as its "
            "own concept"
        )
    what = {
        "subclass": f"sub-class {r.get('via')!r}",
        "near-subclass": f"near match of sub-class {r.get('via')!r}",
        "near-label": f"near match of label {r.get('via')!r}",
        "embedding": f"nearest name {r.get('via')!r}, cosine {r.get('cosine')}{_next(r)}",
    }.get(how, how)
    return f"query {r['from']!r} resolved to label {r['to']!r} ({what})"


def _of_label(r: dict) -> str:
    near = r.get("nearest")
    return f" of label {near!r}" if near and near != r.get("via") else ""


def _next(r: dict) -> str:
    nxt = r.get("next")
    return f"; next label {nxt!r}, {r.get('next_cosine')}" if nxt else ""


def _under(r: dict) -> str:
    least = r.get("min_similarity")
    return f" < min_similarity {least}" if isinstance(least, (int, float)) else ""
