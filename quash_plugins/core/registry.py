"""Plugin registry: one entry-point group per plugin kind.

Built-ins register exactly as third parties do, through ``pyproject.toml``::

    [project.entry-points."quash_plugins.encoders"]
    my-encoder = "my_package.encoder:MyEncoder"

Listing reads distribution metadata only; a plugin is imported on first use and the
class is cached. An unknown name is answered with the known ones, a plugin that fails
to import is reported with its distribution (one warning per process) while the others
keep working, and a name claimed by two distributions is an error unless qualified as
``dist:name``, except that a built-in keeps its bare name: a third-party plugin that
claims ``none`` cannot break the default config (a warning says how to choose it).

Examples
--------
>>> from quash_plugins import registry
>>> "svm-rbf" in registry.available("classifiers")
True
>>> clf = registry.create("classifiers", "svm-rbf", C=2.0)
>>> clf.C
2.0
"""

from __future__ import annotations

import contextlib
import inspect
import logging
import sys
from typing import Any

from ._distributions import (  # noqa: F401 - re-exported: the public names
    _DISTRIBUTIONS,
    distribution_is_editable,
    distribution_of,
    is_editable,
    note_distribution,
)
from ._entry_points import (  # noqa: F401 - re-exported: the public names
    BUILTIN_DIST,
    GROUP_PREFIX,
    KINDS,
    MisplacedEntryPoint,
    PluginInfo,
    _lock,
    _scanned,
    misplaced_entry_points,
    scan,
)
from .errors import (
    ConfigError,
    PluginError,
    QuashError,
    closest,
    install_hint,
    missing_module,
    unknown_name_message,
)
from .once import first_time

log = logging.getLogger(__name__)

_SINGULAR = {k[:-1]: k for k in KINDS}
_TITLE = {
    "encoders": "Encoder",
    "heuristics": "Heuristic",
    "classifiers": "Classifier",
    "adapters": "Adapter",
}


_manual: dict[str, list[PluginInfo]] = {k: [] for k in KINDS}


def normalize_kind(kind: str) -> str:
    """Accept ``"encoders"`` or ``"encoder"``; reject anything else with the known kinds."""
    k = str(kind).strip().lower()
    k = _SINGULAR.get(k, k)
    if k not in KINDS:
        raise PluginError(f"Unknown plugin kind {kind!r}. Known: {', '.join(KINDS)}.")
    return k


def _not_found(kind: str, name: str) -> str:
    """The unknown-name error, plus where ``name`` is registered instead, if anywhere."""
    short = name.split(":", 1)[-1]
    hints = [
        f"A plugin named {short!r} is registered as {k[:-1]} (in group "
        f"{GROUP_PREFIX + k!r}), not as {kind[:-1]}."
        for k in KINDS
        if k != kind and any(i.name == short for i in _all(k))
    ]
    hints += [m.message() for m in misplaced_entry_points() if m.name == short]
    # Where the name is registered answers the error; a similar name would mislead.
    msg = unknown_name_message(_TITLE[kind], name, available(kind), guess=not hints)
    return " ".join([msg, *hints])


def refresh() -> None:
    """Forget scanned entry points (after installing a plugin at run time)."""
    with _lock:
        _scanned.clear()


def _all(kind: str) -> list[PluginInfo]:
    return [*scan(kind), *_manual[kind]]


def register(
    kind: str, name: str, obj: Any, *, dist: str = "__main__", replace: bool = False
) -> None:
    """Register a plugin class (or factory) in this process, for notebooks and tests.

    Parameters
    ----------
    kind
        ``"encoders"``, ``"heuristics"``, ``"classifiers"`` or ``"adapters"``.
    name
        The name configs will use.
    obj
        The plugin class, or a callable returning an instance.
    dist
        Label shown as the distribution; defaults to ``"__main__"``.
    replace
        Replace an earlier registration of the same name from the same ``dist``.
    """
    kind = normalize_kind(kind)
    with _lock:
        existing = [i for i in _manual[kind] if i.name == name and i.dist == dist]
        if existing and not replace:
            raise PluginError(
                f"{_TITLE[kind]} {name!r} is already registered by {dist!r}; "
                "pass replace=True to replace it."
            )
        _manual[kind] = [i for i in _manual[kind] if i not in existing]
        target = f"{getattr(obj, '__module__', '?')}:{getattr(obj, '__qualname__', repr(obj))}"
        info = PluginInfo(kind, name, target, dist, "", _obj=obj)
        _validate(info, obj)
        _manual[kind].append(info)


def unregister(kind: str, name: str, *, dist: str = "__main__") -> None:
    """Remove a plugin registered with :func:`register`."""
    kind = normalize_kind(kind)
    with _lock:
        _manual[kind] = [i for i in _manual[kind] if not (i.name == name and i.dist == dist)]


def available(kind: str) -> list[str]:
    """Sorted names registered for ``kind``; reads metadata only, imports nothing."""
    return sorted({i.name for i in _all(normalize_kind(kind))})


def plugins(kind: str | None = None, *, load: bool = False) -> list[PluginInfo]:
    """Every registered plugin (optionally loading each to report its status)."""
    kinds = KINDS if kind is None else (normalize_kind(kind),)
    out: list[PluginInfo] = []
    for k in kinds:
        for info in _all(k):
            if load:
                with contextlib.suppress(PluginError):
                    _load_info(info)
            out.append(info)
    return out


def _resolve(kind: str, name: str) -> PluginInfo:
    kind = normalize_kind(kind)
    name = str(name).strip()
    infos = _all(kind)
    if ":" in name:
        dist, short = name.split(":", 1)
        for i in infos:
            if i.name == short and _same_dist(i.dist, dist):
                return i
        claims = [i.qualified for i in infos if i.name == short]
        if claims:
            raise PluginError(
                f"{_TITLE[kind]} {short!r} is not provided by distribution {dist!r}. "
                f"It is provided by: {', '.join(claims)}."
            )
        raise PluginError(_not_found(kind, name))
    matches = [i for i in infos if i.name == name]
    if not matches:
        raise PluginError(_not_found(kind, name))
    dists = {i.dist for i in matches}
    if len(dists) > 1:
        builtin = [i for i in matches if _same_dist(i.dist, BUILTIN_DIST)]
        if builtin:
            others = sorted(i.qualified for i in matches if i not in builtin)
            _warn_once(
                ("shadow", kind, name),
                f"{_TITLE[kind]} {name!r} is also claimed by {', '.join(others)}; the "
                f"built-in one keeps the name. Write {others[0]!r} in the config to use "
                "the other one.",
            )
            return builtin[0]
        raise PluginError(
            f"{_TITLE[kind]} {name!r} is claimed by several distributions: "
            f"{', '.join(sorted(dists))}. Qualify it as one of: "
            f"{', '.join(sorted(i.qualified for i in matches))}."
        )
    return matches[0]


def _same_dist(a: str, b: str) -> bool:
    def norm(s: str) -> str:
        return s.lower().replace("_", "-").replace(".", "-")

    return norm(a) == norm(b)


_BASES: dict[str, tuple[str, ...]] = {
    # fingerprint keys the text cache; a class that does not subclass Encoder lacks it.
    "encoders": ("encode_text", "dim", "fingerprint"),
    "heuristics": ("expand",),
    "classifiers": ("fit", "decision_function", "get_params", "set_params"),
    "adapters": ("sniff", "read"),
}


def _validate(info: PluginInfo, obj: Any) -> None:
    if not callable(obj):
        raise PluginError(
            f"{_TITLE[info.kind]} plugin {info.name!r} from distribution {info.dist!r} "
            f"points at {info.target}, which is not a class or factory."
            + _not_callable_hint(info, obj)
        )
    if inspect.isclass(obj):
        _check_interface(info, obj)
        _check_dim(info, obj)
        # A subclass of Encoder & co. inherits the abstract methods, so hasattr passes;
        # it still cannot be built until it implements them.
        abstract = sorted(getattr(obj, "__abstractmethods__", ()) or ())
        if abstract:
            raise PluginError(
                f"{_TITLE[info.kind]} plugin {info.name!r} from distribution {info.dist!r} "
                f"({info.target}) breaks the {info.kind[:-1]} interface: it does not "
                f"implement {', '.join(abstract)} (abstract in its base class)."
            )


def _not_callable_hint(info: PluginInfo, obj: Any) -> str:
    """What an entry point naming a module or an instance should name instead."""
    module = info.target.partition(":")[0]
    if inspect.ismodule(obj):
        what = f"It names the module {obj.__name__!r}"
        base = _base_of(info.kind)
        classes = sorted(
            n
            for n, v in vars(obj).items()
            if inspect.isclass(v)
            and issubclass(v, base)
            and v is not base
            and getattr(v, "__module__", "") == obj.__name__
        )
        target = f"{obj.__name__}:{classes[0]}" if len(classes) == 1 else f"{module}:ClassName"
    else:
        cls = type(obj)
        what = f"It names an instance of {cls.__qualname__}"
        target = f"{cls.__module__}:{cls.__qualname__}"
    if info._loader is None:  # registered in the process: no entry point to edit
        return f" {what}: register the class or a function that returns an instance."
    return (
        f" {what}: the entry point {info.name!r} in group {GROUP_PREFIX + info.kind!r} of "
        f"{info.dist!r} (its pyproject.toml) must name the class, or a function that "
        f'returns an instance: {info.name} = "{target}".'
    )


def _base_of(kind: str) -> type:
    """The interface class of plugin ``kind`` (``quash_plugins.Encoder`` for encoders)."""
    from . import interfaces

    return getattr(interfaces, "MapAdapter" if kind == "adapters" else _TITLE[kind])


def _check_dim(info: PluginInfo, cls: type) -> None:
    """An encoder's ``dim`` is read as a number (``encoder.dim``): one written as a plain
    method (``def dim(self)`` without ``@property``) would fail later as a bare TypeError
    about a 'method', naming no plugin."""
    if info.kind != "encoders":
        return
    dim = inspect.getattr_static(cls, "dim", None)
    if inspect.isfunction(dim) or isinstance(dim, (staticmethod, classmethod)):
        raise PluginError(
            f"Encoder plugin {info.name!r} from distribution {info.dist!r} ({info.target}) "
            f"defines dim as a method of {cls.__qualname__}, so encoder.dim is a method, "
            "not the embedding dimension: decorate it with @property (or set dim = D as a "
            "class or instance attribute)."
        )


def _check_interface(info: PluginInfo, obj: Any) -> None:
    """Raise naming what ``obj`` (a plugin class or a factory's instance) lacks."""
    missing = [a for a in _BASES[info.kind] if not hasattr(obj, a)]
    if not missing:
        return
    base = _base_of(info.kind)
    of = obj if inspect.isclass(obj) else type(obj)
    hint = "" if issubclass(of, base) else f" Subclass quash_plugins.{base.__name__}."
    # Another kind's plugin (an Encoder under quash_plugins.heuristics): the entry point
    # is in the wrong group, and subclassing this kind's base is not the fix.
    other = next((k for k in KINDS if k != info.kind and issubclass(of, _base_of(k))), None)
    if other is not None and not issubclass(of, base):
        hint = f" It is {'an' if other[0] in 'aeiou' else 'a'} {other[:-1]} " + (
            f"(quash_plugins.{_base_of(other).__name__}): move the entry point {info.name!r} "
            f"from group {GROUP_PREFIX + info.kind!r} to {GROUP_PREFIX + other!r} in the "
            f"pyproject.toml of {info.dist!r} and reinstall it."
            if info._loader is not None
            else f"(quash_plugins.{_base_of(other).__name__}): register it as {other!r}."
        )
    raise PluginError(
        f"{_TITLE[info.kind]} plugin {info.name!r} from distribution {info.dist!r} "
        f"({info.target}) breaks the {info.kind[:-1]} interface: it lacks "
        f"{', '.join(missing)}.{hint}"
    )


def _import_hint(info: PluginInfo, exc: BaseException) -> str:
    """What to do about ``exc``, raised while importing ``info.target``: an entry point
    that names a module or object that does not exist, or a missing dependency."""
    module, _, attr = info.target.partition(":")
    if isinstance(exc, SystemExit):
        return (
            f"Module {module!r} calls sys.exit() while it is imported: raise an exception "
            "instead, or do the check when the plugin is built."
        )
    if isinstance(exc, SyntaxError) and exc.filename and exc.lineno:
        # Python names the file by its base name only ('utils.py, line 3'): which one?
        return f"Fix line {exc.lineno} of {exc.filename}."
    where = (
        f"check the entry point {info.name!r} in group {GROUP_PREFIX + info.kind!r} of "
        f"{info.dist!r} (its pyproject.toml)"
    )
    # Not an ImportError from inside the module (``from pkg import typo``), which names
    # an installed module: the module named, or a package above it, is not there.
    missing = getattr(exc, "name", None) if isinstance(exc, ModuleNotFoundError) else None
    if missing and (module == missing or module.startswith(missing + ".")):
        parent, _, last = module.rpartition(".")
        if not attr and hasattr(sys.modules.get(parent), last):  # pkg.Class for pkg:Class
            return (
                f"The module {module!r} it names does not exist: {where}; a colon separates "
                f'the module from the object: {info.name} = "{parent}:{last}".'
            )
        return f"The module {module!r} it names does not exist: {where}."
    missing = missing_module(exc)
    if missing:
        return f"It {install_hint(missing, info.dist)}"
    if isinstance(exc, AttributeError) and attr:
        mod = sys.modules.get(module)
        first = attr.split(".")[0]
        if mod is not None and not hasattr(mod, first):
            names = [n for n in dir(mod) if not n.startswith("_")]
            guess = closest(first, names)
            hint = f" Did you mean {module}:{guess}?" if guess else ""
            return f"Module {module!r} has no {first!r}: {where}.{hint}"
    return ""


def _load_info(info: PluginInfo) -> Any:
    with _lock:
        if info._obj is not None:
            info.status = "ok"
            return info._obj
        if info.error is not None:
            raise PluginError(info.error) from info.exception
        try:
            obj = info._loader() if info._loader else None
        # SystemExit too: a module that calls sys.exit() when imported (a licence or
        # driver check) would otherwise end `quash plugins` and, through adapter: auto,
        # every query. KeyboardInterrupt still stops the command.
        except (Exception, SystemExit) as exc:  # noqa: BLE001 - reported, not raised raw
            info.status = "error"
            info.exception = exc
            hint = _import_hint(info, exc)
            info.error = (
                f"{_TITLE[info.kind]} plugin {info.name!r} from distribution "
                f"{info.dist!r} {info.version} failed to import ({info.target}): "
                f"{type(exc).__name__}: {str(exc).rstrip('.')}. {hint}".rstrip()
                + f" Fix or uninstall {info.dist!r}."
            )
            raise PluginError(info.error) from exc
        try:
            _validate(info, obj)
        except PluginError as exc:
            info.status = "error"
            info.error = f"{exc} Fix or uninstall {info.dist!r}."
            info.exception = exc
            raise PluginError(info.error) from None
        info._obj = obj
        info.status = "ok"
        return obj


def warn_skipped(kind: str, name: str, exc: PluginError) -> None:
    """For a caller that goes on without a plugin that failed to load (``adapter: auto``
    tries every adapter): warn once per plugin that it is skipped. A caller that needed
    the plugin raises the error instead, with no warning before it saying otherwise."""
    _warn_once(("broken", kind, name), f"{exc} It is skipped.")


def _warn_once(key: tuple[str, str, str], message: str) -> None:
    """Log ``message`` as a warning the first time ``key`` is seen in this process."""
    if first_time(("registry", *key)):
        log.warning("%s", message)


def load(kind: str, name: str) -> Any:
    """Import (once) and return the plugin class or factory registered as ``name``."""
    return _load_info(_resolve(kind, name))


def info(kind: str, name: str) -> PluginInfo:
    """The :class:`PluginInfo` for ``name`` (without loading it)."""
    return _resolve(kind, name)


def _init_params(obj: Any) -> list[inspect.Parameter] | None:
    """The parameters a plugin (a class, or a factory) is built with, ``self`` left out;
    ``[]`` for a class without a constructor of its own, None when its signature cannot
    be read."""
    if inspect.isclass(obj) and obj.__init__ is object.__init__:
        return []  # no constructor of its own: it takes no parameters
    target = obj.__init__ if inspect.isclass(obj) else obj
    try:
        params = list(inspect.signature(target).parameters.values())
    except (TypeError, ValueError):
        return None
    return params[1:] if inspect.isclass(obj) and params else params


def _by_keyword(p: inspect.Parameter) -> bool:
    return p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)


def accepted_params(obj: Any) -> list[str] | None:
    """Keyword parameters a plugin accepts, or None when it takes ``**kwargs``."""
    params = _init_params(obj)
    if params is None or any(p.kind is p.VAR_KEYWORD for p in params):
        return None
    return [p.name for p in params if p.name != "self" and _by_keyword(p)]


def required_params(obj: Any) -> list[str]:
    """Keyword parameters a plugin cannot be built without (no default); [] when its
    signature cannot be read."""
    return [p.name for p in _init_params(obj) or () if p.default is p.empty and _by_keyword(p)]


def create(kind: str, name: str, /, **params: Any) -> Any:
    """Build the plugin ``name`` of ``kind`` with ``params`` as keyword arguments.

    An unknown parameter is rejected with the list of accepted ones; a classifier's
    ``check_params()``, when it has one, runs here, so a bad value fails at build time.

    Examples
    --------
    >>> from quash_plugins import registry
    >>> registry.create("heuristics", "none").expand("chair").positives
    ['chair']
    """
    kind = normalize_kind(kind)
    entry = _resolve(kind, name)
    obj = _load_info(entry)
    accepted = accepted_params(obj)
    if accepted is not None:
        unknown = [p for p in params if p not in accepted]
        if unknown:
            bad = unknown[0]
            # 0.6: a typo, not a different word ('check_finite' is not 'cache_frames', 0.5)
            guess = closest(bad, accepted, cutoff=0.6)
            hint = f" Did you mean {guess!r}?" if guess else ""
            raise ConfigError(
                f"{_TITLE[kind]} {entry.name!r} does not accept parameter {bad!r}. "
                f"Accepted: {', '.join(accepted) or '(none)'}.{hint}"
            )
    needed = [p for p in required_params(obj) if p not in params]
    if needed:
        # Python's own "__init__() missing 1 required positional argument" names neither
        # the plugin's distribution nor where the value goes.
        version = f" {entry.version}" if entry.version else ""
        given = ", ".join(f"{p}: ..." for p in needed)
        them = "them" if len(needed) > 1 else "it"
        cli = (
            f"; quash make-scene: {' '.join(f'--encoder-option {p}=...' for p in needed)}"
            if kind == "encoders"
            else ""
        )
        raise ConfigError(
            f"{_TITLE[kind]} {entry.name!r} from distribution {entry.dist!r}{version} "
            f"needs parameter{'s' if len(needed) > 1 else ''} "
            f"{', '.join(repr(p) for p in needed)}, which {'were' if len(needed) > 1 else 'was'} "
            f"not given: write {them} beside the name in the config ({kind[:-1]}: "
            f"{{name: {entry.name}, {given}}}{cli}), or give {entry.target} a default "
            f"for {them}."
        )
    try:
        instance = obj(**params)
        # scikit-learn estimators validate in fit, not __init__; a classifier's
        # check_params() lets a bad config value fail here, before any model loads.
        check = getattr(instance, "check_params", None) if kind == "classifiers" else None
        if callable(check):
            check()
    except (TypeError, ValueError) as exc:
        if _same_dist(entry.dist, BUILTIN_DIST):
            raise ConfigError(f"{_TITLE[kind]} {entry.name!r}: {exc}") from exc
        # A third-party plugin's: a value it refuses, or a bug in its __init__; say whose,
        # with what it was given, as for any other exception it raises when built.
        given = f" with {', '.join(params)}" if params else ""
        raise ConfigError(
            f"{_TITLE[kind]} {entry.name!r} from distribution {entry.dist!r}"
            f"{f' {entry.version}' if entry.version else ''} failed to build{given}: "
            f"{type(exc).__name__}: {str(exc).rstrip('.')}. Check its parameters in the "
            f"config, or fix or uninstall {entry.dist!r}; --debug shows the traceback."
        ) from exc
    except QuashError:
        raise
    except Exception as exc:
        missing = missing_module(exc)  # a plugin that imports its dependencies when built
        if missing is not None:
            raise PluginError(
                f"{_TITLE[kind]} {entry.name!r} from distribution {entry.dist!r} cannot be "
                f"built: it {install_hint(missing, entry.dist)} ({type(exc).__name__}: {exc})"
            ) from exc
        if isinstance(exc, ImportError) and _same_dist(entry.dist, BUILTIN_DIST):
            # installed, but without what was imported from it: another version
            raise PluginError(
                f"{_TITLE[kind]} {entry.name!r} cannot be built: {type(exc).__name__}: "
                f"{str(exc).rstrip('.')}. An installed package lacks what it imports: "
                "install the versions quash-plugins requires (its pyproject.toml)."
            ) from exc
        if _same_dist(entry.dist, BUILTIN_DIST):
            raise
        # A third-party plugin's own error (a weights file it cannot open...): say whose.
        given = f" with {', '.join(params)}" if params else ""
        raise PluginError(
            f"{_TITLE[kind]} {entry.name!r} from distribution {entry.dist!r}"
            f"{f' {entry.version}' if entry.version else ''} failed to build{given}: "
            f"{type(exc).__name__}: "
            f"{str(exc).rstrip('.')}. Check its parameters in the config, or fix or "
            f"uninstall {entry.dist!r}; --debug shows the traceback."
        ) from exc
    if not inspect.isclass(obj):  # a factory: its class was not checked when it loaded
        _check_interface(entry, instance)
        try:
            _check_dim(entry, type(instance))
        except PluginError as exc:
            raise PluginError(f"{exc} Fix or uninstall {entry.dist!r}.") from None
    if getattr(instance, "name", None) in (None, "encoder", "heuristic", "adapter"):
        with contextlib.suppress(AttributeError):
            instance.name = entry.name
    with contextlib.suppress(AttributeError):  # what messages call it (interfaces.plugin_name)
        # as the config wrote it: 'dist:name' names another distribution's plugin than
        # the bare name (the built-in one), and messages must tell them apart
        instance._quash_plugin_name = entry.qualified if ":" in str(name) else entry.name
    return instance
