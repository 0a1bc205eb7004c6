"""The offline demo: a generated 3D indoor scene and the comparison run on it.

- :mod:`~quash_plugins.demo.classes`: the scene's classes (appearance and language names).
- :mod:`~quash_plugins.demo.scene`: the proxy scene generator (``quash make-scene``).
- :mod:`~quash_plugins.demo.runner`: ``quash demo`` (evaluation plus the Rerun recording).

Rule: the demo is a user of the package: it may import the engine, evaluation, the
viewer and the public API of the plugin packages.
"""
