"""The four plugin interfaces: :class:`Encoder`, :class:`Heuristic`, :class:`Classifier`
and :class:`MapAdapter`.

A plugin is a class built with its configuration parameters as keyword arguments and
registered under an entry point (see :mod:`quash_plugins.core.registry`). Conformance is
checked by :mod:`quash_plugins.testing`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import weakref
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from sklearn.base import BaseEstimator
from sklearn.utils import ClassifierTags

from .errors import EncoderError
from .expansions import CosineExpansion, KernelExpansion
from .once import first_time
from .redact import is_secret_param
from .types import DEFAULT_NEGATIVES, LatentMap, QuerySet

log = logging.getLogger(__name__)


class Encoder(ABC):
    """A text encoder whose embedding space matches a map's.

    Subclasses set :attr:`name`, implement :attr:`dim` and :meth:`encode_text`, and
    should override :meth:`fingerprint` when the weights can change under the same name.
    """

    #: Stable identifier (used in cache keys and messages).
    name: str = "encoder"
    #: Torch-style device string, or None for encoders that do not use one.
    device: str | None = None

    @property
    @abstractmethod
    def dim(self) -> int:
        """Embedding dimension D."""

    @abstractmethod
    def encode_text(self, texts: Sequence[str]) -> np.ndarray:
        """Embed ``texts``; return ``(len(texts), dim)`` float32 with unit-norm rows.

        One row per text, in order, each independent of the others in the batch. The
        empty string ``""`` is a text like any other: embed it (one finite unit-norm row)
        or refuse it with an :class:`~quash_plugins.core.errors.EncoderError` that says
        so; never a zero or NaN row. ``quash_plugins.testing.check_encoder`` checks this.
        """

    def encode_images(self, images: Any) -> np.ndarray:
        """Optional: global image embeddings ``(n, dim)``. Not every encoder has an image tower."""
        raise NotImplementedError(f"Encoder {self.name!r} has no image tower.")

    def config(self) -> dict[str, Any]:
        """Parameters that identify this encoder's output (for fingerprints and provenance).

        By default: the instance's public attributes whose values are plain data
        (strings, numbers, booleans, None, and lists or dicts of them), less ``device``.
        Override it to name exactly what changes the output (a model object held in an
        attribute is not plain data, so say which weights it loaded).
        """
        return {
            k: v
            for k, v in sorted(vars(self).items())
            if not k.startswith("_") and k != "device" and _plain(v)
        }

    def fingerprint(self) -> str:
        """Identity of the embedding function: changes whenever its output could change.

        Hashes the class, ``name``, ``dim``, :meth:`config` and the name and version of
        the installed distribution that provides the class, so that upgrading a plugin
        package never serves text embeddings cached by the version before. When no
        version names the code (a class in a script or a local module, or a package
        installed with ``pip install -e``), the source is hashed too
        (:func:`source_digest`: every ``.py`` file of the class's top-level package, or
        the module file of a class outside a package; for a built-in encoder, the files
        of ``quash_plugins/encoders``), so that editing ``encode_text``, or a helper
        module it calls, does.
        """
        payload = {
            "class": f"{type(self).__module__}.{type(self).__qualname__}",
            "name": self.name,
            "dim": self.dim,
            "config": self.config(),
            "normalized": True,
        }
        from .registry import distribution_of

        dist = distribution_of(type(self).__module__)
        if dist is not None:
            payload["distribution"] = dist
        source = source_digest(type(self))
        if source is not None:
            payload["source"] = source
        blob = json.dumps(payload, sort_keys=True, default=str).encode()
        return f"{self.name}-{hashlib.sha256(blob).hexdigest()[:16]}"


#: Class -> its source digest (or None): computed once per class (an edited module
#: imported again is a new class, and is hashed again).
_SOURCE_DIGESTS: weakref.WeakKeyDictionary[type, str | None] = weakref.WeakKeyDictionary()
#: Bounds of a package's digest: beyond them only the class's module file is hashed.
PACKAGE_DIGEST_MAX_FILES = 1000
PACKAGE_DIGEST_MAX_BYTES = 32 * 2**20


def source_digest(cls: type) -> str | None:
    """A digest of the source of ``cls``'s code, when a version does not name that code:
    no distribution installed it (a script, a local module, a test file) or an editable
    install did (:func:`~quash_plugins.core.registry.is_editable`). None for a released
    install, whose version names its code, and when no source can be found.

    For a class in a package, every ``.py`` file of its top-level package is hashed
    (their paths within it and their content), so that editing a helper module the
    encoder imports changes the digest too (for a class of this project, the files of
    its subpackage: :func:`digest_package`); a package of more than
    :data:`PACKAGE_DIGEST_MAX_FILES` files or :data:`PACKAGE_DIGEST_MAX_BYTES` bytes
    hashes the class's module file only (a debug line says so). A class in a single-file
    module (a script) hashes that file, and a class with no file (an interactive
    session) its own source. Computed once per class.
    """
    try:
        return _SOURCE_DIGESTS[cls]
    except (KeyError, TypeError):
        pass
    digest = _compute_source_digest(cls)
    with contextlib.suppress(TypeError):  # a class that cannot be weakly referenced
        _SOURCE_DIGESTS[cls] = digest
    return digest


def _compute_source_digest(cls: type) -> str | None:
    import inspect
    import sys

    from .registry import distribution_of, is_editable

    module = cls.__module__
    if distribution_of(module) is not None and not is_editable(module):
        return None
    path = getattr(sys.modules.get(module), "__file__", None)
    try:
        if not path:
            return hashlib.sha256(inspect.getsource(cls).encode()).hexdigest()[:16]
        root = digest_package(module)
        package = _package_digest(root) if root is not None else None
        if package is not None:
            return package
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]
    except (OSError, TypeError):
        return None


def digest_package(module: str) -> str | None:
    """The package whose ``.py`` files :func:`source_digest` hashes for a class defined in
    ``module``: its top-level package, or, for a class of this project itself, the
    subpackage it sits in (``quash_plugins.encoders``; None, i.e. the module file, for a
    module directly under the top level). This project's other modules (the CLI, the
    viewer, evaluation) change with nearly every commit of an editable install and do not
    change what a built-in encoder returns; hashing them changed every built-in
    fingerprint, and so emptied the text cache and warned about every map built before,
    after any edit or ``git pull``.

    Examples
    --------
    >>> digest_package("my_plugin.nets.clip"), digest_package("quash_plugins.encoders._table")
    ('my_plugin', 'quash_plugins.encoders')
    """
    parts = module.split(".")
    if parts[0] != __name__.partition(".")[0]:
        return parts[0]
    return ".".join(parts[:2]) if len(parts) > 2 else None


def _package_digest(top: str) -> str | None:
    """A digest of every ``.py`` file under the package ``top`` (paths relative to its
    folder, in order, and contents), or None: ``top`` is no package (a single-file
    module) or exceeds the bounds."""
    import sys

    roots = list(getattr(sys.modules.get(top), "__path__", None) or [])
    if not roots:
        return None
    files: list[tuple[str, Path]] = []
    for root in roots:
        for path in Path(root).rglob("*.py"):
            rel = path.relative_to(root)
            if any(part.startswith(".") for part in rel.parts):
                continue
            files.append((rel.as_posix(), path))
            if len(files) > PACKAGE_DIGEST_MAX_FILES:
                log.debug(
                    "package %s has over %d .py files: its fingerprint hashes only the "
                    "encoder's module file",
                    top,
                    PACKAGE_DIGEST_MAX_FILES,
                )
                return None
    sha = hashlib.sha256()
    total = 0
    for rel, path in sorted(files):
        data = path.read_bytes()
        total += len(data)
        if total > PACKAGE_DIGEST_MAX_BYTES:
            log.debug(
                "package %s has over %d bytes of .py files: its fingerprint hashes only "
                "the encoder's module file",
                top,
                PACKAGE_DIGEST_MAX_BYTES,
            )
            return None
        sha.update(rel.encode() + b"\0" + hashlib.sha256(data).digest())
    return sha.hexdigest()[:16]


def _plain(value: Any, *, written: bool = False) -> bool:
    """True for JSON-like data: strings, numbers, booleans, None, and lists or string-keyed
    mappings of them; what a default :meth:`Encoder.config` records.

    ``written``: as a map's file records it (``core.encoder_record``): finite numbers only
    (JSON has no NaN or infinity), and no key inside named like a credential
    (:func:`~quash_plugins.core.redact.is_secret_param`)."""
    if value is None or isinstance(value, (str, bool, int)):
        return True
    if isinstance(value, float):
        return not written or math.isfinite(value)
    if isinstance(value, (list, tuple)):
        return all(_plain(v, written=written) for v in value)
    if isinstance(value, dict):
        return all(
            isinstance(k, str)
            and not (written and is_secret_param(k))
            and _plain(v, written=written)
            for k, v in value.items()
        )
    return False


def plugin_name(plugin: Any) -> str:
    """The name a message calls ``plugin`` by: the one it was registered and built under
    (what a config writes; a factory entry point may build an instance of a class with
    another ``name``), else its ``name``, else its class's name."""
    registered = getattr(plugin, "_quash_plugin_name", None)
    if isinstance(registered, str) and registered:
        return registered
    return str(getattr(plugin, "name", None) or type(plugin).__name__)


def _contract_warning(who: str, what: str, message: str) -> None:
    if not first_time(("encoder-contract", who, what)):
        return
    logging.getLogger(__name__).warning(
        "Encoder %r %s. The encoder contract is (n, dim) float32 rows of unit norm; "
        "quash_plugins.testing.check_encoder checks it.",
        who,
        message,
    )


def check_text_embeddings(
    emb: Any,
    texts: Sequence[str],
    dim: int,
    who: str,
    normalize: bool = True,
    *,
    warn_norm: bool = True,
    origin: str | None = None,
) -> np.ndarray:
    """Validate an encoder's output at the boundary and return unit-norm float32.

    Raises :class:`EncoderError` naming the encoder (and ``origin``, its module and
    distribution, when given) when the shape or values are wrong, with what to run.
    Output that breaks the contract in a way that can be mended (not float32, rows not of
    unit norm) is mended, with one warning per encoder and process: the conformance kit
    fails such an encoder. ``warn_norm=False``: rows off unit norm are expected (an
    encoder configured with ``normalize: false``) and renormalised without a warning.
    """
    named = f"Encoder {who!r}" + (f" ({origin})" if origin else "")
    fix = (
        " Fix its encode_text: it must return one unit-norm (len(texts), dim) float32 row "
        "per text; quash_plugins.testing.check_encoder(encoder) checks the contract."
    )
    if emb is None:  # read as a 0-d NaN array: "returned shape ()" named no cause
        raise EncoderError(
            f"{named} returned None for {len(texts)} texts (does its encode_text end "
            f"without a 'return'?).{fix}"
        )
    kind = f"{type(emb).__module__.partition('.')[0]}.{type(emb).__name__}"
    if not isinstance(emb, np.ndarray) and callable(getattr(emb, "detach", None)):
        # A torch tensor: np.asarray refuses one on a GPU or with gradients.
        _contract_warning(who, "tensor", f"returns a {kind}, not a numpy array; converted to one")
        try:
            emb = emb.detach().float().cpu().numpy()
        except Exception as exc:  # noqa: BLE001 - reported with the encoder's name
            raise EncoderError(
                f"Encoder {who!r} returned a {kind} that cannot be made a numpy array "
                f"({type(exc).__name__}: {exc}); return .detach().float().cpu().numpy()."
            ) from exc
    dtype = getattr(emb, "dtype", None)
    if dtype is not None and dtype != np.float32:
        _contract_warning(who, "dtype", f"returns {dtype} embeddings; converted to float32")
    elif dtype is None and isinstance(emb, (list, tuple)):
        _contract_warning(
            who, "container", f"returns a {kind} of rows, not a numpy array; converted to one"
        )
    try:
        arr = np.asarray(emb, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise EncoderError(
            f"Encoder {who!r} returned a {kind} that is not an array of numbers "
            f"({exc}); return a (len(texts), {dim}) float32 numpy array."
        ) from exc
    if arr.shape != (len(texts), dim):
        raise EncoderError(
            f"{named} returned shape {arr.shape} for {len(texts)} texts; "
            f"expected ({len(texts)}, {dim}), dim being its 'dim'.{fix}"
        )
    if not np.isfinite(arr).all():
        row = int(np.argwhere(~np.isfinite(arr))[0][0])
        raise EncoderError(f"{named} returned NaN or Inf embeddings (for {texts[row]!r}).{fix}")
    if normalize and len(arr):
        norms = np.linalg.norm(arr, axis=1, keepdims=True)
        if (norms == 0).any():
            bad = texts[int(np.argmin(norms[:, 0]))]
            raise EncoderError(f"{named} returned a zero embedding for {bad!r}.{fix}")
        off = float(np.abs(norms - 1.0).max())
        if warn_norm and off > 1e-3:
            _contract_warning(
                who, "norm", f"returns rows of norm up to {1 + off:.3g} from 1; renormalised"
            )
        arr = arr / norms
    return np.ascontiguousarray(arr, dtype=np.float32)


@dataclass
class ExpansionContext:
    """What a heuristic may use besides the query text.

    Attributes
    ----------
    encoder
        The active encoder (for heuristics that embed a vocabulary or resolve labels).
    label_names
        The map's ground-truth label names, when known.
    map
        The map being queried (for map-mined negatives).
    seed
        Seed for random heuristics; the same seed gives the same set.
    negatives
        The generic negatives of the config (added by the pipeline afterwards).
    """

    encoder: Encoder | None = None
    label_names: list[str] | None = None
    map: LatentMap | None = None
    seed: int | None = 0
    negatives: tuple[str, ...] = DEFAULT_NEGATIVES
    extra: dict[str, Any] = field(default_factory=dict)

    def rng(self, salt: str = "") -> np.random.Generator:
        """A generator seeded from ``seed`` and ``salt`` (e.g. the query), stable across runs."""
        digest = hashlib.sha256(f"{self.seed}|{salt}".encode()).digest()
        return np.random.default_rng(int.from_bytes(digest[:8], "little"))


class Heuristic(ABC):
    """Expands a query into a :class:`QuerySet` of positives and negatives."""

    name: str = "heuristic"

    @abstractmethod
    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        """Return the query set for ``query``. Random heuristics use ``context.seed``."""

    def params(self) -> dict[str, Any]:
        """Parameters recorded in the query set's provenance."""
        return {k: v for k, v in vars(self).items() if not k.startswith("_")}

    def provenance(self, context: ExpansionContext | None, **extra: Any) -> dict[str, Any]:
        out: dict[str, Any] = {"heuristic": self.name, "params": self.params()}
        if context is not None and context.seed is not None:
            out["seed"] = context.seed
        out.update(extra)
        return out


class Classifier(BaseEstimator):
    """A scikit-learn estimator trained on text embeddings and applied to map items.

    Contract (scikit-learn's): ``__init__`` stores its keyword arguments unchanged and
    validates nothing; parameters are validated in ``fit``; fitted state ends in ``_``.
    ``fit(X, y)`` takes ``X (n, D)`` float32 unit-norm text embeddings and ``y (n,)``
    with 1 for positives and 0 for negatives (any two labels work: the larger one,
    ``classes_[1]``, is the positive class). ``decision_function(E)`` returns ``(m,)``
    with positive values for matches.

    The estimator tags declare a binary-only classifier on dense input, so
    scikit-learn's ``check_estimator`` feeds two-class targets. A classifier may define
    ``check_params()``, which validates its parameters without fitting (and which
    ``fit`` calls): :func:`~quash_plugins.core.registry.create` calls it, so a bad value
    in a config fails when the classifier is built, before any model is loaded.
    """

    def __sklearn_tags__(self) -> Any:
        tags = super().__sklearn_tags__()
        tags.estimator_type = "classifier"
        tags.classifier_tags = ClassifierTags(multi_class=False)
        tags.target_tags.required = True
        tags.input_tags.sparse = False
        tags.input_tags.allow_nan = False
        return tags

    def fit(self, X: np.ndarray, y: np.ndarray) -> Classifier:  # pragma: no cover - abstract
        raise NotImplementedError

    def decision_function(self, E: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def predict(self, E: np.ndarray) -> np.ndarray:
        """The class of each row: ``classes_[1]`` (1, a match) where
        ``decision_function(E) > 0``, else ``classes_[0]``; booleans when the classifier
        sets no ``classes_``."""
        match = np.asarray(self.decision_function(E)) > 0
        classes = getattr(self, "classes_", None)
        if classes is None or len(classes) != 2:
            return match
        return np.asarray(classes)[match.astype(np.intp)]

    def postprocess_scores(self, scores: np.ndarray) -> np.ndarray:
        """Map-level rescaling of the full score vector (e.g. min-max). Identity by default."""
        return scores

    def display_scores(self, scores: np.ndarray, threshold: float = 0.0) -> np.ndarray:
        """Scores mapped to [0, 1] for display, 0.5 at ``threshold``. Logistic by default."""
        s = np.subtract(scores, np.float32(threshold), dtype=np.float32)
        spread = float(np.std(s)) if s.size else 1.0
        scale = spread if spread > 1e-6 else 1.0
        # in place, one buffer: 0.5 * (1 + tanh(s / (2 scale))) in float32
        np.divide(s, np.float32(2.0 * scale), out=s)
        np.tanh(s, out=s)
        s += np.float32(1.0)
        s *= np.float32(0.5)
        return s

    def describe(self) -> str:
        """Short description for tables and the Rerun document."""
        params = ", ".join(f"{k}={v!r}" for k, v in sorted(self.get_params(deep=False).items()))
        return f"{type(self).__name__}({params})"


@runtime_checkable
class StackableClassifier(Protocol):
    """Optional protocol: a classifier whose fitted decision function is a kernel expansion.

    ``f(x) = sum_i coef_i k(x, s_i) + b`` with an RBF, cosine-RBF or linear-cosine kernel
    (:class:`~quash_plugins.core.kernels.KernelPart`). The engine stacks the expansions of
    every query being answered into one GEMM per block of the map, so ``query_many``
    reads the map once. Built-in and third-party classifiers take part on equal terms:
    implement ``kernel_expansion`` and return None until fitted.
    """

    def kernel_expansion(self) -> KernelExpansion | None: ...


@runtime_checkable
class CosineClassifier(Protocol):
    """Optional protocol: a classifier whose decision is a function of cosine similarities.

    ``decision(x) = reduce(c)`` with ``c[:, j] = cos(x, labels[j])``
    (:class:`~quash_plugins.core.kernels.CosineExpansion`), as for the peers' rules
    (``contrast``, ``label-argmax``, ``nearest-sample``, ``lerf-relevancy``,
    ``cosine-threshold``). The engine puts every such query's label columns into the same
    GEMM per block as the stacked SVMs, so a batch of queries reads the map once, and it
    never normalises the map to get cosines. Return None until fitted, or when the
    decision is not such a function (e.g. a subclass that overrides
    ``decision_function``): the engine then calls ``decision_function`` on prepared
    blocks.
    """

    def cosine_expansion(self) -> CosineExpansion | None: ...


class MapAdapter(ABC):
    """Reads a map file, directory or live object into a :class:`LatentMap`.

    Constructor keyword arguments are the adapter's options (e.g. ``gs``, ``cs``); the
    same options may be overridden per call in :meth:`read`.
    """

    name: str = "adapter"
    #: File-name endings of this adapter's maps (``(".npz",)``). With ``adapter: auto``,
    #: a file that no ``sniff`` accepts but whose name ends so is read with this adapter,
    #: so that its own error says what is wrong with the file.
    suffixes: tuple[str, ...] = ()
    #: Shell-style patterns of the names of this adapter's map files, for formats whose
    #: files have no suffix of their own (``("grid_lseg_*.npy",)``): used as ``suffixes``
    #: are, and such a file beside another format's map folder makes that folder
    #: ambiguous (both are named; the user chooses).
    file_names: tuple[str, ...] = ()
    #: Leading bytes of this adapter's files (``(b"\x89HDF\r\n\x1a\n",)``), used the
    #: same way when no suffix matches.
    magic: tuple[bytes, ...] = ()
    #: Sub-folders that mark a folder as this adapter's (``("vlmap", "vlmap_cam")``):
    #: tried first, so that a folder holding one but not its map file is read with this
    #: adapter and its error names the missing file.
    folders: tuple[str, ...] = ()

    @abstractmethod
    def sniff(self, source: Any) -> bool:
        """True when this adapter can read ``source``. Must be cheap and never raise."""

    @abstractmethod
    def read(self, source: Any, **options: Any) -> LatentMap:
        """Read ``source`` read-only and return a validated :class:`LatentMap`."""

    def unrecognised_hint(self, source: Any) -> str:
        """A sentence for a ``source`` that no adapter's :meth:`sniff` accepts but that a
        user may have meant for this one (the RGB folder of a feature map), added to the
        "No adapter recognises" error of ``adapter: auto``; ``""`` when there is nothing
        to say (the default). Must be cheap and never raise."""
        return ""

    def options(self, overrides: dict[str, Any]) -> dict[str, Any]:
        """The constructor's options, updated by per-call ``overrides`` from :meth:`read`.

        An override that the constructor does not accept raises
        :class:`~quash_plugins.core.errors.MapFormatError` naming the accepted options.
        """
        from .errors import MapFormatError
        from .registry import accepted_params

        names = accepted_params(type(self)) or []
        unknown = sorted(set(overrides) - set(names))
        if unknown:
            raise MapFormatError(
                f"Adapter {self.name!r} has no option(s) {unknown}. "
                f"Options: {', '.join(names) or '(none)'}."
            )
        return {**{n: getattr(self, n) for n in names}, **overrides}

    def write_example(self, directory: Path) -> Any:
        """Write a small valid example under ``directory`` and return its source.

        Used by the conformance kit. Adapters for live objects may return the object.
        """
        raise NotImplementedError
