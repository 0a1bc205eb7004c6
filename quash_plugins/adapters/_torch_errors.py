"""What a ``torch.load(weights_only=True)`` failure tells the user.

torch's own text for a refused file is written for a terminal (ANSI colour codes) and
advises loading again with ``weights_only=False``, which runs any code the file holds.
The adapters never pass that advice on: :func:`weights_only_refusal` turns such a
failure into a :class:`~quash_plugins.core.errors.MapFormatError` that names the file,
what it holds (the global it references, or the pickle opcode torch's safe loader does
not read) and the safe fix the caller gives (re-save the data as plain tensors or numpy).
Any other text of torch's that is shown goes through :func:`clean_text` first.
"""

from __future__ import annotations

import re
from pathlib import Path

from ..core.errors import MapFormatError

#: ANSI escape sequences (colours, bold) in a terminal-bound message.
ANSI = re.compile(r"\x1b\[[0-?]*[ -/]*[@-~]")
_GLOBAL = re.compile(r"GLOBAL ([\w.]+)")
_OPERAND = re.compile(r"Unsupported operand (\d+)")


def clean_text(text: str) -> str:
    """``text`` without ANSI escape sequences."""
    return ANSI.sub("", text)


def first_line(exc: BaseException) -> str:
    """The first non-empty line of ``exc``'s message, cleaned; its type name if none."""
    for line in clean_text(str(exc)).splitlines():
        if line.strip():
            return line.strip()
    return type(exc).__name__


def _pickle_proto(code: int) -> int:
    """The pickle protocol that introduced opcode ``code``; -1 for no opcode."""
    import pickletools

    for op in pickletools.opcodes:
        if ord(op.code) == code:
            return op.proto
    return -1


def is_weights_only_error(exc: BaseException) -> bool:
    """True when ``exc`` is torch's safe loader refusing what a file holds."""
    text = str(exc)
    return "Weights only load failed" in text or "WeightsUnpickler" in text


def weights_only_refusal(
    exc: BaseException,
    path: Path | str,
    what: str,
    fix: str,
    allowed: str = "tensors and plain containers of them (dicts, lists, tuples)",
) -> MapFormatError:
    """The refusal of a file that ``torch.load(weights_only=True)`` would not load.

    Names ``path``, says it holds objects other than tensors and plain containers (the
    global it references, when torch says which) or a pickle opcode the safe loader does
    not read, what is loaded (``allowed``), and ends with ``fix``. Never suggests
    ``weights_only=False``.
    """
    text = clean_text(str(exc))
    hit, operand = _GLOBAL.search(text), _OPERAND.search(text)
    if hit:
        found = (
            f"holds objects other than tensors and plain containers (it references {hit.group(1)})"
        )
    elif operand and _pickle_proto(int(operand.group(1))) > 2:
        found = (
            f"is pickled with an opcode ({operand.group(1)}) of pickle protocol "
            f"{_pickle_proto(int(operand.group(1)))}, which the safe loader does not read "
            "(torch.save's default protocol is 2)"
        )
    elif operand:  # no pickle opcode: a damaged file, or not one torch.save wrote
        return MapFormatError(
            f"{path}: not a readable {what}: torch's safe loader stopped at byte value "
            f"{operand.group(1)}, which is no pickle opcode it reads (a damaged file, or "
            f"not one torch.save wrote). {fix}"
        )
    else:
        found = "holds objects other than tensors and plain containers"
    return MapFormatError(
        f"{path}: refused: the {what} {found}. Only {allowed} are loaded (torch.load with "
        f"weights_only=True): unpickling anything else could run code from the file. {fix}"
    )
