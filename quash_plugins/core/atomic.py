"""Safe outputs: they appear whole or not at all, and never replace what the user owns.

The policy, the same for every file quash-plugins writes:

- An output is never one of the inputs (the same file through any symbolic or hard
  link), never inside an input folder, and never a symbolic link, a device, a pipe or
  a folder of another kind. ``--force`` does not change this.
- The command line replaces an existing file only when it is recognisably a previous
  output of the same kind (a ``quash query`` result, a ``quash eval`` report...), or
  with ``--force``. Everything else that exists is refused before any work is done.
- The Python writers (``write_results_npz``, ``write_npz_map``, ``write_zarr_map``,
  ``LazyQuery.to_zarr``, ``convert_map``, ``write_vlmaps_map``) refuse their own input
  map, every file read with it (its ``source["inputs"]``) and non-regular targets, and
  otherwise replace the file they are given, as ``open(path, "w")`` does.
- Every write goes to a hidden temporary file (or folder) beside the target, renamed
  over it at the end; an error, Ctrl-C or SIGTERM removes it. Its name says that quash
  made it, on which machine and in which process (``.NAME.quash-tmp-HOST-PID-RANDOM``),
  and the writer holds a lock on ``.NAME.quash-lck-HOST-PID-RANDOM`` meanwhile: a
  process killed outright (SIGKILL, a power cut) cannot remove it, so the next write of
  the same output removes those whose lock is free and process gone (:func:`remove_stale`).

:func:`check_output` applies the first two rules, :func:`check_distinct_outputs` refuses
two outputs of one command naming the same file; :func:`atomic_write` and
:func:`atomic_dir` write.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import secrets
import shutil
import stat
import threading
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

# the temporary names and the stale ones' removal: remove_stale is public here (the
# naming helpers too, for the tests that check the names)
from ._atomic_stale import _STALE as _STALE
from ._atomic_stale import _host as _host
from ._atomic_stale import _process_gone as _process_gone
from ._atomic_stale import _retag, _tag, hold_lock
from ._atomic_stale import remove_stale as remove_stale
from .errors import UsageError
from .types import source_inputs


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_not_input(
    path: str | Path, inputs: Iterable[str | Path | None] = (), *, what: str = "output"
) -> Path:
    """Refuse an output that is one of ``inputs`` (the same file through any link) or
    lies inside an input folder; return it as a :class:`Path`."""
    out = Path(path).expanduser()
    for src in inputs:
        if src is None or not isinstance(src, (str, os.PathLike)):
            continue
        src = Path(src).expanduser()
        if not src.exists():
            continue
        if out.exists() and _same_file(out, src):
            raise UsageError(
                f"{what} {out} is the input {src}: writing it would replace your data. "
                "Choose another output file."
            )
        if src.is_dir():
            try:
                parent = out.resolve().parent
                root = src.resolve()
            except (OSError, RuntimeError):  # a symbolic-link loop: checked by the caller
                continue
            if parent == root or root in parent.parents:
                raise UsageError(
                    f"{what} {out} lies inside the input folder {src}. Choose an output outside it."
                )
    return out


def _resolved(path: str | Path) -> Path:
    p = Path(path).expanduser()
    try:
        return p.resolve()
    except (OSError, RuntimeError):  # a symbolic-link loop: refused later by check_output
        return Path(os.path.abspath(p))


def check_distinct_outputs(outputs: Iterable[tuple[str, str | Path | None]]) -> None:
    """Refuse two outputs that name the same file: the same path, the same file through
    a relative path or a symbolic link, or two hard links to one file.

    ``outputs`` holds ``(option, path)`` pairs; ``None`` paths are ignored. The second
    write would replace the first, so one output would be lost. An output inside another
    (``--rrd out/q.rrd`` with a folder ``--out out``) is refused too: a folder output is
    replaced whole, and the file inside it would be lost the next time.

    Raises
    ------
    UsageError
        Naming both options and the file.
    """
    seen: list[tuple[str, Path, Path]] = []
    for what, path in outputs:
        if path is None or path == "":
            continue
        out = Path(path).expanduser()
        real = _resolved(out)
        for other_what, other, other_real in seen:
            if real == other_real or (out.exists() and _same_file(out, other)):
                raise UsageError(
                    f"{other_what} {other} and {what} {out} name the same file: the second "
                    f"would replace the first. Give {what} another file name."
                )
            for inner_what, inner, outer_what, outer, outer_real in (
                (what, out, other_what, other, other_real),
                (other_what, other, what, out, real),
            ):
                if outer_real in _resolved(inner).parents:
                    raise UsageError(
                        f"{inner_what} {inner} is inside {outer_what} {outer}, which is "
                        f"written as a whole: {inner_what} would be lost when "
                        f"{outer_what} is written again. Give {inner_what} a path outside "
                        f"{outer}."
                    )
        seen.append((what, out, real))


def check_output(
    path: str | Path,
    inputs: Iterable[str | Path | None] = (),
    *,
    what: str = "output",
    overwrite: bool = False,
    replaceable: Callable[[Path], bool] | None = None,
    folder: bool = False,
) -> Path:
    """Check that writing ``path`` loses nothing; return it as a :class:`Path`.

    Parameters
    ----------
    path
        The output file.
    inputs
        Files or folders this command reads (maps, configs); ``None`` entries are ignored.
    what
        How messages name the output (``"--out"``, ``"--rrd"``...).
    overwrite
        Replace an existing regular file (``--force``).
    replaceable
        Returns True for an existing file that may be replaced without ``overwrite``
        (e.g. a previous result of the same kind).
    folder
        The output is a folder (a zarr store, an export folder) rather than a file. An
        existing folder that is neither a zarr store nor ``replaceable`` is never
        replaced, even with ``overwrite``.

    Raises
    ------
    UsageError
        Naming the output, what is wrong and how to fix it.
    """
    out = check_not_input(path, inputs, what=what)
    try:
        st = out.lstat()
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise UsageError(f"{what} {out}: cannot inspect the path ({exc.strerror}).") from None
    if st is not None:
        if stat.S_ISLNK(st.st_mode):
            raise UsageError(
                f"{what} {out} is a symbolic link; refusing to replace it. Remove the link "
                "or write to another file."
            )
        if stat.S_ISDIR(st.st_mode) and not folder:
            raise UsageError(f"{what} {out} is a folder; give a file name inside it.")
        if folder and not stat.S_ISDIR(st.st_mode):
            raise UsageError(f"{what} {out} exists and is not a folder; refusing to replace it.")
        known = (replaceable is not None and replaceable(out)) or _empty_dir(out)
        if folder and not known and not is_store_dir(out):
            raise UsageError(
                f"{what} {out} is a folder that is neither a zarr store nor a previous "
                "output (a folder holding only the files this command writes); refusing "
                "to replace it (even with --force): what else is in it would be lost. "
                "Choose another name."
            )
        if not folder and not stat.S_ISREG(st.st_mode):
            raise UsageError(
                f"{what} {out} is not a regular file (a device, pipe or socket); refusing "
                "to replace it."
            )
        if not overwrite and not known:
            # with replaceable, a previous output would have been replaced: say why not this
            why = " and is not a previous output of this command" if replaceable else ""
            raise UsageError(
                f"{what} {out} already exists{why}. Pass --force to replace it, or choose "
                "another file."
            )
    parent = out.parent if str(out.parent) else Path(".")
    if parent.exists() and not parent.is_dir():
        raise UsageError(f"{what} {out}: {parent} is not a folder.")
    if parent.exists() and not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"{what} {out}: the folder {parent} is not writable.")
    return out


def refuse_own_input(path: str | Path, source: Any, *, folder: bool = False) -> None:
    """Refuse writing ``path`` when it is the map it was made from or a file read with it.

    ``source`` is a map's ``source`` dict, a path, or a list of them. For a dict, every
    input it records is checked (:func:`~quash_plugins.core.types.source_inputs`: its
    ``path``, the files and folders listed under ``inputs``, such as VLMaps'
    ``obj2cls_dict.txt`` or OpenScene's scene points, and the taxonomy beside the map).
    The same file through any link, and a path inside a source folder, are refused with
    :class:`UsageError` naming the output, the input and the fix, as are non-regular
    targets (a zarr store when ``folder``). Used by the Python writers, which otherwise
    replace what they are given.
    """
    items = [source] if isinstance(source, (dict, str, os.PathLike)) else list(source or [])
    sources: list[Any] = []
    for item in items:
        sources += source_inputs(item) if isinstance(item, dict) else [item]
    check_output(path, sources, what="Output", overwrite=True, folder=folder)


@contextlib.contextmanager
def atomic_write(path: str | Path, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` on success.

    On error, ``KeyboardInterrupt`` or a SIGTERM that the CLI turns into an exception,
    the temporary file is removed and ``path`` is left as it was. A ``path`` that exists
    and is not a regular file (a folder, device, pipe or symbolic link) is refused before
    anything is written. A leading ``~`` is the home folder, as in the checks above.
    """
    path = Path(path).expanduser()
    _refuse_non_regular(path)
    _make_parent(path)
    remove_stale(path)
    tag = _tag("tmp")
    tmp_path = path.parent / f".{path.name}.{tag}{suffix or '.tmp'}"
    # The temporary file is created inside the try block, so that an interrupt at any
    # moment (even between creating it and yielding it) removes it. The lock says to
    # remove_stale that it is being written, whatever PID namespace or machine we are.
    with hold_lock(path, tag):
        try:
            try:
                fd = os.open(tmp_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            except OSError as exc:
                raise UsageError(
                    f"Cannot write {path}: {exc.strerror} ({path.parent}). "
                    "Choose a writable folder."
                ) from None
            os.close(fd)
            yield tmp_path
            if tmp_path.is_file():
                # Created 0600; give the output the permissions of a normal new file.
                os.chmod(tmp_path, 0o666 & ~_umask())
            os.replace(tmp_path, path)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                tmp_path.unlink()
            raise


def _refuse_non_regular(path: Path) -> None:
    try:
        st = path.lstat()
    except FileNotFoundError:
        return
    except OSError as exc:
        raise UsageError(f"Output {path}: cannot inspect the path ({exc.strerror}).") from None
    if not stat.S_ISREG(st.st_mode):
        kind = "symbolic link" if stat.S_ISLNK(st.st_mode) else "non-regular file"
        raise UsageError(f"Output {path} is a {kind}; refusing to replace it.")


def _make_parent(path: Path) -> None:
    """Create ``path``'s folder, or raise a :class:`UsageError` naming the output."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(
            f"Cannot write {path}: {exc.strerror} ({path.parent}). Choose a writable folder."
        ) from None


def make_output_folder(path: str | Path, what: str) -> Path:
    """Create the output folder ``path`` (given as option ``what``) and check that a file
    can be created in it, before any work; raise a :class:`UsageError` naming the folder
    and the option otherwise (a read-only or missing parent, a file in the way)."""
    folder = Path(path).expanduser()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".quash-probe-{secrets.token_hex(6)}"
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        os.unlink(probe)
    except OSError as exc:
        raise UsageError(
            f"{what} {folder}: cannot write there ({exc.strerror or exc}). "
            f"Give {what} a folder you can write to."
        ) from None
    return folder


def _empty_dir(path: Path) -> bool:
    """An empty folder: replacing it loses nothing."""
    try:
        return path.is_dir() and not path.is_symlink() and not any(path.iterdir())
    except OSError:
        return False


def is_store_dir(path: str | Path) -> bool:
    """True when ``path`` is a folder holding zarr metadata at its root (a zarr store)."""
    p = Path(path)
    return (
        p.is_dir()
        and not p.is_symlink()
        and any((p / m).is_file() for m in ("zarr.json", ".zgroup", ".zarray"))
    )


class _LeftAtExit:
    """The temporary folders of failed writes, removed once more when the process exits
    by ONE exit handler (registered on the first): a long-lived process (a notebook) that
    writes many stores that fail does not pile up a handler per write."""

    def __init__(self) -> None:
        self.paths: set[Path] = set()
        self.registered = False
        self.lock = threading.Lock()

    def add(self, path: Path) -> None:
        with self.lock:
            self.paths.add(path)
            if not self.registered:
                atexit.register(self.remove_all)
                self.registered = True

    def remove_all(self) -> None:
        with self.lock:
            paths = list(self.paths)
        for p in paths:
            shutil.rmtree(p, ignore_errors=True)
            if not os.path.lexists(p):
                with self.lock:
                    self.paths.discard(p)


_LEFT = _LeftAtExit()


@contextlib.contextmanager
def atomic_dir(
    path: str | Path,
    overwrite: bool = True,
    replaceable: Callable[[Path], bool] | None = None,
    kind: str = "zarr store",
) -> Iterator[Path]:
    """Yield a temporary folder path beside ``path``; move it into place on success.

    For folder outputs (zarr stores, OpenLex3D folders). The caller creates the
    temporary folder (zarr does). An existing ``path`` is replaced only when
    ``overwrite`` is true and it is empty or ``replaceable(path)`` holds (default: it is
    a zarr store) — never a file, a symbolic link or any other folder. The old folder is
    moved aside first and removed only once the new one is in place; if anything fails
    in between, the old folder is put back. On error or interrupt the temporary folder
    is removed.
    """
    path = Path(path).expanduser()
    remove_stale(path)
    replaceable = replaceable or is_store_dir
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise UsageError(f"Output {path} exists and is not a folder; refusing to replace it.")
    if path.exists():
        if not overwrite:
            raise UsageError(f"{path} exists. Remove it or pass overwrite=True.")
        if not replaceable(path) and not _empty_dir(path):
            raise UsageError(
                f"Output {path} is a folder that is not a previous {kind}; refusing to "
                "replace it. Choose another name."
            )
    _make_parent(path)
    tag = _tag("tmp")
    tmp = path.parent / f".{path.name}.{tag}"
    old = path.parent / f".{path.name}.{_retag(tag, 'old')}"
    # held while tmp or old may exist (tmp is made by the caller, after the yield)
    with hold_lock(path, tag):
        try:
            yield tmp
            if path.exists():
                os.replace(path, old)
            os.replace(tmp, path)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            # a worker process of the same command (Dask) may still write a chunk into it
            # until the command stops its workers: removed again when this process exits
            _LEFT.add(tmp)
            if old.exists() and not path.exists():
                os.replace(old, path)  # put the previous store back
            raise
        shutil.rmtree(old, ignore_errors=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | Path, text: str) -> Path:
    with atomic_write(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
