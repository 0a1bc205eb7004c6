"""Safe outputs: they appear whole or not at all, and never replace what the user owns.

- :func:`check_output` refuses an output that is one of the inputs (the same file
  through any link), that sits inside an input folder, that is not a regular file (a
  folder, a device, a pipe, a symbolic link), or that already exists, unless the
  caller allows replacing it (``--force``, or a previous result of the same kind).
- :func:`atomic_write` writes beside the target and renames over it, and refuses
  non-regular targets itself, whoever calls it.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from .errors import UsageError


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


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
        The output is a folder (a zarr store) rather than a file.

    Raises
    ------
    UsageError
        Naming the output, what is wrong and how to fix it.
    """
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
            parent = out.resolve().parent
            root = src.resolve()
            if parent == root or root in parent.parents:
                raise UsageError(
                    f"{what} {out} lies inside the input folder {src}. Choose an output outside it."
                )
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
        if not folder and not stat.S_ISREG(st.st_mode):
            raise UsageError(
                f"{what} {out} is not a regular file (a device, pipe or socket); refusing "
                "to replace it."
            )
        if not overwrite and not (replaceable is not None and replaceable(out)):
            raise UsageError(
                f"{what} {out} already exists. Pass --force to replace it, or choose another file."
            )
    parent = out.parent if str(out.parent) else Path(".")
    if parent.exists() and not parent.is_dir():
        raise UsageError(f"{what} {out}: {parent} is not a folder.")
    if parent.exists() and not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"{what} {out}: the folder {parent} is not writable.")
    return out


@contextlib.contextmanager
def atomic_write(path: str | Path, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` on success.

    On error the temporary file is removed and ``path`` is left as it was. A ``path``
    that exists and is not a regular file (a folder, device, pipe or symbolic link) is
    refused before anything is written.
    """
    path = Path(path)
    try:
        st = path.lstat()
    except FileNotFoundError:
        st = None
    if st is not None and not stat.S_ISREG(st.st_mode):
        kind = "symbolic link" if stat.S_ISLNK(st.st_mode) else "non-regular file"
        raise UsageError(f"Output {path} is a {kind}; refusing to replace it.")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(
            prefix=f".{path.name}.", suffix=suffix or ".tmp", dir=path.parent
        )
    except OSError as exc:
        raise UsageError(
            f"Cannot write {path}: {exc.strerror} ({path.parent}). Choose a writable folder."
        ) from None
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if tmp_path.is_file():
            # mkstemp creates 0600; give the output the permissions of a normal new file.
            os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | Path, text: str) -> Path:
    with atomic_write(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
