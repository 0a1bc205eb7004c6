"""The core: the data types, the four plugin interfaces, the registry and the config.

Rule: ``core`` imports nothing of this package outside ``core`` (no plugin package, no
engine), so a third-party plugin depends on exactly what a built-in one does. The
optional protocols a plugin may implement to take part in an optimisation (one GEMM per
block for kernel classifiers, :class:`~quash_plugins.core.interfaces.StackableClassifier`,
and for cosine rules, :class:`~quash_plugins.core.interfaces.CosineClassifier`) are
defined here too. See ``docs/architecture.md``.
"""
