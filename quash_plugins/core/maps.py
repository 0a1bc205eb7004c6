"""Reading a map with the adapter that recognises it (``adapter="auto"``) or by name.

These know no adapter by name: they ask every registered adapter through the registry,
so a third-party adapter is detected exactly as a built-in one is.

Errors name the file and say what to do. When no adapter's ``sniff`` accepts a file but
its name or first bytes say whose it is (an adapter's ``suffixes`` and ``magic``), that
adapter reads it anyway, so that its own error (truncated, unreadable, a missing field)
is reported instead of "No adapter recognises". Failures an adapter does not turn into
a :class:`MapFormatError` itself (out of memory for a declared shape, a permission
error, a symbolic-link loop, a decompression error) are reported with the file's name.
"""

from __future__ import annotations

import errno
import fnmatch
import logging
from pathlib import Path
from typing import Any

from . import registry
from .errors import MapFormatError, PluginError, QuashError, near_paths
from .types import LatentMap, record_inputs

log = logging.getLogger(__name__)


def _ordered_adapters() -> list[tuple[str, Any]]:
    """Loadable adapters by ``priority`` (highest first), then name. A broken one is
    skipped, with a warning once per process."""
    candidates = []
    for name in registry.available("adapters"):
        try:
            cls = registry.load("adapters", name)
        except PluginError as exc:
            registry.warn_skipped("adapters", name, exc)
            continue
        candidates.append((-int(getattr(cls, "priority", 0)), name, cls))
    return [(name, cls) for _, name, cls in sorted(candidates, key=lambda c: (c[0], c[1]))]


def claimed_by(source: Any) -> tuple[str, str] | None:
    """``(adapter, why)`` for the adapter whose ``folders``, ``suffixes`` or ``magic`` match
    ``source``.

    Sub-folders (a scene folder holding ``vlmap/``) are tried first, then suffixes,
    over every adapter, then leading bytes; None when nothing claims the path (or it is
    not a path).
    """
    if not isinstance(source, (str, Path)):
        return None
    path = Path(source)
    adapters = _ordered_adapters()
    for name, cls in adapters:  # a folder holding the sub-folder a format writes
        for sub in getattr(cls, "folders", ()) or ():
            if (path / sub).is_dir():
                return name, f"it holds a {sub}/ folder"
    name_lower = path.name.lower()
    for name, cls in adapters:
        for suffix in getattr(cls, "suffixes", ()) or ():
            if name_lower.endswith(str(suffix).lower()):
                return name, f"its name ends in {suffix}"
    for name, cls in adapters:
        pattern = _named(cls, path.name)
        if pattern and path.is_file():
            return name, f"its name is that of the format's files ({pattern})"
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError:
        return None
    for name, cls in adapters:
        for magic in getattr(cls, "magic", ()) or ():
            if magic and head.startswith(magic):
                return name, "its first bytes are those of that format"
    return None


def detect_adapter(source: Any, *, claimed: bool = False) -> str:
    """Name of the first registered adapter whose ``sniff`` accepts ``source``.

    Adapters are tried in order of their ``priority`` attribute (highest first), then name.
    With ``claimed``, when none accepts it, the adapter whose ``suffixes``/``magic`` match
    is returned instead (reading with it reports why the file is not a valid map).

    A folder that one adapter reads but that also directly holds a map file another
    adapter reads (a ConceptFusion ``pointclouds/`` beside a portable ``map.npz``) is
    refused: which of the two is meant is the user's choice (:func:`check_no_other_maps`).
    """
    for name, cls in _ordered_adapters():
        if _sniffs(cls, source):
            check_no_other_maps(source, name)
            return name
    if claimed:
        claim = claimed_by(source)
        if claim is not None:
            log.debug("no adapter recognises %s, but %s: trying %s", source, claim[1], claim[0])
            return claim[0]
    path = isinstance(source, (str, Path))
    if not path and hasattr(source, "shape") and hasattr(source, "dtype"):
        # no adapter reads a bare array: "Pass adapter=NAME" sent one round them all
        shape = tuple(int(n) for n in source.shape)
        tensor = " (a torch tensor: tensor.cpu().numpy())" if hasattr(source, "cpu") else ""
        raise MapFormatError(
            f"The {type(source).__name__} of shape {shape} is not a map: no adapter reads a "
            "bare array. Wrap the (N, D) embeddings in a LatentMap and query that: "
            "LatentMap(embeddings, kind='points', positions=xyz) (from quash_plugins import "
            f"LatentMap; kind='voxels' with grid_index and voxel_size){tensor}."
        )
    what = str(source) if path else type(source).__name__
    choose = "--adapter NAME" if path else "adapter=NAME"
    raise MapFormatError(
        f"No adapter recognises {what}.{_hints(source)} Known adapters: "
        f"{', '.join(registry.available('adapters'))}. Pass {choose} to choose one."
        f"{_maps_inside(source)}"
    )


def check_no_other_maps(source: Any, chosen: str, limit: int = 256) -> None:
    """Refuse a folder that ``chosen`` reads when it also holds, directly, a map file of
    another format: a file whose name ends in a suffix another adapter declares
    (``suffixes``: ``.npz``, ``.zarr``...) and which that adapter's ``sniff`` accepts
    (a results file or an unrelated archive is no map), or a file named as another
    adapter's ``file_names`` say and accepted by it (OpenScene's ``<scene>_<n>.pt``, a
    VLMaps ``grid_lseg_1.npy``). ``chosen``'s own files (a frame it reads) do not count.
    The message names the folder, both candidates and how to choose: ``--adapter NAME``
    for the folder, or the file's path. At most ``limit`` entries of the folder are
    looked at (a debug line says when more are skipped).
    """
    if not isinstance(source, (str, Path)) or not Path(source).is_dir():
        return
    folder = Path(source)
    adapters = _ordered_adapters()
    candidates = [(name, cls) for name, cls in adapters if name != chosen]
    if not any(getattr(c, "suffixes", ()) or getattr(c, "file_names", ()) for _, c in candidates):
        return
    chosen_cls = dict(adapters).get(chosen)
    others = []
    for entry in _entries(folder, limit, "other maps"):
        lower = entry.name.lower()
        for name, cls in candidates:
            suffixed = any(lower.endswith(str(x).lower()) for x in getattr(cls, "suffixes", ()))
            named = entry.is_file() and _named(cls, entry.name)
            if not (suffixed or named) or not _sniffs(cls, entry):
                continue
            if chosen_cls is None or not _sniffs(chosen_cls, entry):
                others.append((entry, name))
            break
    if not others:
        return
    listed = ", ".join(f"{path} ({name})" for path, name in others)
    first = others[0][0]
    raise MapFormatError(
        f"{folder} is a {chosen} map folder, but it also holds "
        f"{'another map' if len(others) == 1 else 'other maps'}: {listed}. Which one is "
        f"meant is ambiguous: pass --adapter {chosen} (adapter={chosen!r} in Python) to read "
        f"the folder as {chosen}, or pass the file itself (e.g. {first}) to read it."
    )


def _named(cls: Any, file_name: str) -> str | None:
    """The first of ``cls.file_names`` (shell patterns) that ``file_name`` matches."""
    for pattern in getattr(cls, "file_names", ()) or ():
        if fnmatch.fnmatchcase(file_name, pattern):
            return str(pattern)
    return None


def _entries(folder: Path, limit: int, purpose: str) -> list[Path]:
    """The first ``limit`` entries of ``folder`` by name, hidden ones left out (a debug
    line says when more are skipped); ``[]`` when it cannot be listed."""
    try:
        entries = sorted(p for p in folder.iterdir() if not p.name.startswith("."))
    except OSError:
        return []
    if len(entries) > limit:
        log.debug(
            "%s: %d entries; looking at the first %d for %s", folder, len(entries), limit, purpose
        )
    return entries[:limit]


def _sniffs(cls: Any, source: Any) -> bool:
    """``cls().sniff(source)``; False when the sniff itself fails."""
    try:
        return bool(cls().sniff(source))
    except Exception as exc:  # noqa: BLE001 - a faulty sniff must not break detection
        log.debug("adapter %s failed to sniff %r: %s", getattr(cls, "name", cls), source, exc)
        return False


def _hints(source: Any) -> str:
    """What the adapters say of a source none of them reads (``unrecognised_hint``): the
    hint an adapter gives when it is named (``--adapter image-features`` on a folder of
    RGB images), given under ``auto`` too; each as a sentence, or ``""``."""
    said = []
    for name, cls in _ordered_adapters():
        try:
            hint = str(cls().unrecognised_hint(source) or "").strip()
        except Exception as exc:  # noqa: BLE001 - a faulty hint must not hide the error
            log.debug("adapter %s failed to give a hint for %r: %s", name, source, exc)
            continue
        if hint and hint not in said:
            said.append(hint)
    return "".join(f" {h}" for h in said)


def _maps_inside(source: Any, limit: int = 64) -> str:
    """For a folder no adapter takes: the files and sub-folders one does (a project
    folder holding a map folder and a feature folder, a folder of two ``.npz`` maps),
    as a sentence; else ``""``."""
    if not isinstance(source, (str, Path)) or not Path(source).is_dir():
        return ""
    found = []
    for sub in _entries(Path(source), limit, "maps inside it"):
        for name, cls in _ordered_adapters():
            if _sniffs(cls, sub):
                found.append(f"{sub} ({name})")
                break
    if not found:
        return ""
    return f" Maps inside it: {', '.join(found)}; pass one of them."


def check_map_path(path: Path) -> Path:
    """Refuse a map path that does not exist, is a symbolic-link loop or a broken link,
    or cannot be inspected; the message names the path and the fix: for a missing map,
    the maps with a near name (:func:`~quash_plugins.core.errors.near_paths`: another
    suffix, a close name, or in a folder named like a missing one)."""
    try:
        path.stat()
    except FileNotFoundError:
        if path.is_symlink():
            raise MapFormatError(
                f"Map {path} is a symbolic link to {_readlink(path)}, which does not exist."
            ) from None
        near = near_paths(path, keep=_a_map)
        hint = f"Did you mean {' or '.join(near)}?" if near else "Check the path."
        raise MapFormatError(f"Map not found: {path}. {hint}") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise MapFormatError(
                f"Map {path} is a symbolic-link loop (it points back at itself). Point it "
                "at the map file or folder."
            ) from None
        raise MapFormatError(_os_message(path, exc)) from None
    return path


def _a_map(path: Path) -> bool:
    """Whether an adapter claims or reads ``path``: a near name offered for a missing map
    is a map (``scene.npz`` for ``scene.npy``), not the recording or taxonomy beside it."""
    return claimed_by(path) is not None or any(_sniffs(cls, path) for _, cls in _ordered_adapters())


def _readlink(path: Path) -> str:
    try:
        return str(path.readlink())
    except OSError:
        return "?"


def _os_message(where: Any, exc: OSError) -> str:
    target = exc.filename or where
    if isinstance(exc, PermissionError):
        return (
            f"{where}: permission denied reading {target}. Check that you may read the map's "
            "files (and enter its folders)."
        )
    if exc.errno == errno.ELOOP:
        return f"{where}: {target} is a symbolic-link loop."
    return (
        f"{where}: cannot read {target} ({exc.strerror or exc}). The file may be damaged, "
        "truncated or on a disk that is not available."
    )


def map_read_error(
    where: Any, exc: BaseException, adapter: str | None = None, rows: str = ""
) -> MapFormatError:
    """A :class:`MapFormatError` for a failure reading a map, naming the file and the fix.

    ``rows`` names what was being read (``"rows 0-999 of the embeddings"``), when the
    failure came while the map's rows were read rather than when it was opened.
    """
    what = f" ({rows})" if rows else ""
    if isinstance(exc, MemoryError):
        return MapFormatError(
            f"{where}: reading it{what} needs more memory than this machine has ({exc}). The "
            "file may declare a wrong shape (damaged or truncated); if the map really is "
            "that large, convert it to zarr (quash convert MAP MAP.zarr) and query it with "
            "--backend dask."
        )
    if isinstance(exc, OSError):
        return MapFormatError(_os_message(where, exc) + (f" While reading {rows}." if rows else ""))
    by = f" with adapter {adapter!r}" if adapter else ""
    return MapFormatError(
        f"{where}: cannot read it{by}{what}: {type(exc).__name__}: {exc}. The file may be "
        "damaged or truncated (a corrupt chunk or block); convert or copy it again from the "
        "original map."
    )


def resolve_adapter(source: Any, adapter: str | None = "auto") -> tuple[Any, str]:
    """``(source, name)``: a path source checked and expanded, ``"auto"`` resolved by sniffing.

    Raises :class:`MapFormatError` for a path that does not exist, a broken link or a
    symbolic-link loop. With ``"auto"``, a file no sniff accepts but whose suffix or magic
    an adapter claims resolves to that adapter (see :func:`detect_adapter`).
    """
    if isinstance(source, (str, Path)):
        source = check_map_path(Path(source).expanduser())
    name = detect_adapter(source, claimed=True) if adapter in (None, "auto") else str(adapter)
    return source, name


def source_name(source: Any) -> str:
    """How a message names ``source``: a path as it is, a live object by its type, never
    by its ``repr`` (which may print whole arrays).

    >>> from types import SimpleNamespace
    >>> source_name("map.npz"), source_name(SimpleNamespace(grid_feat=[[0.0] * 512]))
    ('map.npz', 'live SimpleNamespace object')
    """
    return (
        str(source) if isinstance(source, (str, Path)) else f"live {type(source).__name__} object"
    )


def live_adapter(source: Any, configured: str) -> str | None:
    """For a live object (not a path) that adapter ``configured`` does not recognise, the
    adapter whose ``sniff`` does (``vlmaps-live`` for a VLMaps ``VLMap``); else None.

    A config written for map files (``adapter: {name: vlmaps}``) then still reads the
    live object that a program hands to ``Quash.query``. An unknown ``configured`` is
    None here, and reported when the map is read.
    """
    if isinstance(source, (str, Path, LatentMap)):
        return None
    try:
        if registry.load("adapters", configured)().sniff(source):
            return None
    except PluginError:
        return None
    except Exception as exc:  # noqa: BLE001 - a faulty sniff counts as a refusal
        log.debug("adapter %s failed to sniff a %s: %s", configured, type(source).__name__, exc)
    return _other_reader(source, configured)


def read_map(source: Any, adapter: str = "auto", **options: Any) -> LatentMap:
    """Read ``source`` (path or live object) into a :class:`LatentMap`, read-only.

    The map's ``source["inputs"]`` lists every file or folder read for it: what its
    adapter recorded, its ``path`` and the taxonomy beside it
    (:func:`~quash_plugins.core.types.record_inputs`). A :class:`LatentMap` is returned
    as it is.
    """
    if isinstance(source, LatentMap):
        return source
    source, name = resolve_adapter(source, adapter)
    reader = registry.create("adapters", name, **options)
    try:
        lmap = reader.read(source)
    except QuashError as exc:
        other = _other_reader(source, name) if adapter not in (None, "auto") else None
        if other is not None and not isinstance(source, (str, Path)):
            raise _other_adapter_error(source, name, other) from exc
        if other is not None:
            raise type(exc)(
                f"{exc} It looks like a {other!r} map, not a {name!r} one: choose the "
                f"adapter {other!r} (--adapter {other}, or --adapter auto to detect it)."
            ) from exc
        claim = _claim_for(source, name)
        shown = "" if isinstance(source, (str, Path)) else str(source)
        if claim is None and len(shown) > 1 and shown in str(exc):  # never dump the arrays
            raise type(exc)(str(exc).replace(shown, source_name(source))) from exc
        if claim is None:
            raise
        raise type(exc)(
            f"{source} looks like a {name!r} map ({claim}) but cannot be read: {exc}"
        ) from exc
    except Exception as exc:  # noqa: BLE001 - anything else is reported with the file's name
        if not isinstance(source, (str, Path)):
            other = _other_reader(source, name) if adapter not in (None, "auto") else None
            if other is not None:
                raise _other_adapter_error(source, name, other) from exc
            raise MapFormatError(
                f"The {name!r} adapter cannot read this {source_name(source)} "
                f"({type(exc).__name__}: {exc}). Pass a map file's path, a LatentMap, or "
                "adapter=NAME naming an adapter that reads such objects."
            ) from exc
        raise map_read_error(str(source), exc, name) from exc
    if not isinstance(lmap, LatentMap):
        raise PluginError(f"Adapter {name!r} returned {type(lmap).__name__}, not a LatentMap.")
    lmap.source.setdefault("adapter", name)
    if isinstance(source, Path):
        lmap.source.setdefault("path", str(source))
    record_inputs(lmap.source)  # the path and the taxonomy beside it, whatever the adapter
    log.info("read %s", lmap.describe())
    return lmap


def _other_adapter_error(source: Any, name: str, other: str) -> MapFormatError:
    """Adapter ``name`` was asked to read a program's live object that ``other`` reads:
    the fix as a program gives it (``adapter=...``), not a command line's ``--adapter``."""
    return MapFormatError(
        f"The {name!r} adapter cannot read this {source_name(source)}; it looks like a "
        f"{other!r} map: read it with adapter={other!r} (or 'auto', which detects it)."
    )


def _other_reader(source: Any, name: str) -> str | None:
    """The adapter other than ``name`` whose ``sniff`` accepts ``source``, or None. Only
    asked when reading with an adapter the user chose has already failed."""
    try:
        other = detect_adapter(source)
    except QuashError:
        return None
    return other if other != name else None


def _claim_for(source: Any, name: str) -> str | None:
    """Why ``source`` looks like adapter ``name``'s although its sniff refuses it (a
    damaged file), or None. Only asked when reading has already failed."""
    claim = claimed_by(source)
    if claim is None or claim[0] != name:
        return None
    try:
        if registry.load("adapters", name)().sniff(source):
            return None  # a file of that format whose content the adapter refuses
    except Exception:  # noqa: BLE001 - sniff never raises, but a plugin's might
        pass
    return claim[1]


# ---------------------------------------------------------------------------------------
# File-backed arrays that travel by reference (a Dask task reopens them on the worker)

#: ``(filename, offset, shape, dtype)`` of a memory-mapped array (see :func:`memmap_ref`).
MemmapRef = tuple[str, int, tuple[int, ...], str]


def memmap_ref(array: Any) -> MemmapRef | None:
    """``(filename, offset, shape, dtype)`` of a C-ordered array whose bytes lie in a
    file through a memory map (``np.load(mmap_mode="r")``, ``np.memmap(...)``, or a
    contiguous view of one: a reshape, a range of rows, ``np.asarray`` of it), else None.

    The offset is the view's own (a slice of a ``np.memmap`` keeps its parent's
    ``offset`` attribute, which would be wrong). A copy-on-write map (mode ``"c"``) may
    hold values its file does not, so it has no reference. :func:`open_memmap_ref` opens
    the same values again, read-only: an array-like that pickles a reference instead of
    its values keeps a Dask task graph small whatever the size of the file.

    Examples
    --------
    >>> import numpy as np, os, tempfile
    >>> path = os.path.join(tempfile.mkdtemp(), "a.npy")
    >>> np.save(path, np.arange(6, dtype=np.float32).reshape(3, 2))
    >>> mm = np.load(path, mmap_mode="r")
    >>> ref = memmap_ref(mm)
    >>> ref[1:], memmap_ref(mm[1:])[1]
    ((128, (3, 2), '<f4'), 136)
    >>> open_memmap_ref(memmap_ref(mm[1:]))[1].tolist(), memmap_ref(np.zeros(3))
    ([4.0, 5.0], None)
    """
    import mmap

    import numpy as np

    if not isinstance(array, np.ndarray) or not array.flags.c_contiguous or array.size == 0:
        return None
    root: Any = array
    while isinstance(root, np.ndarray) and not (
        isinstance(root, np.memmap) and isinstance(root.base, mmap.mmap)
    ):
        root = root.base
    if root is None or not isinstance(root, np.memmap) or not root.filename:
        return None
    if getattr(root, "mode", "r") == "c":
        return None
    delta = array.__array_interface__["data"][0] - root.__array_interface__["data"][0]
    if delta < 0 or delta + array.nbytes > root.nbytes:
        return None
    shape = tuple(int(s) for s in array.shape)
    return (str(root.filename), int(root.offset) + int(delta), shape, array.dtype.str)


def open_memmap_ref(ref: MemmapRef) -> Any:
    """The read-only :class:`numpy.memmap` a :func:`memmap_ref` describes."""
    import numpy as np

    filename, offset, shape, dtype = ref
    return np.memmap(filename, np.dtype(dtype), "r", offset=int(offset), shape=tuple(shape))
