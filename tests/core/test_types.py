"""QueryResult's account of the presence check (the CLI table and the viewer use it)."""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins.core.types import QueryResult, QuerySet


@pytest.mark.parametrize(
    "info, expected",
    [
        (None, "off"),
        ({"checked": False, "why": "the map has no voxel grid"}, "not checked: the map has no"),
        ({"checked": True, "present": True, "kept": 2, "components": 5}, "present (2 of 5"),
        ({"checked": True, "present": False, "components": 0}, "absent: nothing matched"),
        (
            {"checked": True, "present": False, "components": 3, "best_margin": 0.0123},
            "absent: no component won clearly against the other labels (best margins: "
            "grown region +0.012)",
        ),
        (
            {"checked": True, "present": False, "components": 3, "best_margin": None},
            "absent: no component large enough",
        ),
        (
            {"checked": True, "present": False, "components": 128, "best_margin": None}
            | {"largest_component": 5, "min_component": 8},
            "absent: all 128 components are smaller than min_component=8 (largest: 5 items)",
        ),
        (
            {"checked": True, "present": False, "components": 1, "best_margin": None}
            | {"largest_component": 1, "min_component": 8},
            "absent: the only component (1 item) is smaller than min_component=8",
        ),
        (
            {"checked": True, "present": False, "components": 2, "best_margin": None}
            | {"largest_component": 9, "min_component": 8},
            "absent: no component of at least min_component=8 items beat every negative by "
            "flat_margin",
        ),
    ],
)
def test_a_result_says_what_the_presence_check_decided(info, expected):
    prov = {} if info is None else {"presence": info}
    qs = QuerySet("sofa", ["sofa"], ["cushion"], prov)
    result = QueryResult(qs, np.zeros(4, bool), np.zeros(4, np.float32), np.zeros(4, np.float32))
    assert result.presence.startswith(expected), result.presence
    assert result.summary()["presence"] == result.presence


def test_a_result_and_its_instances_print_in_one_line():
    """``print(result)`` in a notebook printed every field: the query set's hundreds of
    negatives, the arrays and every index of every instance (thousands of lines)."""
    from quash_plugins.core.types import Instance

    n = 50_000
    negatives = [f"negative {i}" for i in range(300)]
    qs = QuerySet("chair", ["chair", "seat"], negatives, {"presence": {"checked": False}})
    mask = np.zeros(n, bool)
    mask[100:877] = True
    indices = np.flatnonzero(mask)
    inst = Instance(
        0, indices, np.array([2.53581, 0.4893, -3.68848]), np.zeros(3), np.ones(3), 0.72031
    )
    result = QueryResult(
        qs,
        mask,
        np.zeros(n, np.float32),
        np.zeros(n, np.float32),
        instances=[inst],
        config_name="quash-labels",
    )
    text = repr(result)
    assert "\n" not in text and len(text) < 200, text
    assert f"matched={int(mask.sum())} of {n}" in text and "'chair'" in text
    assert "instances=1" in text and "quash-labels" in text and result.presence in text
    assert "negative 0" not in text
    one = repr(inst)
    assert "\n" not in one and len(one) < 120, one
    assert f"size={len(indices)}" in one and "2.54, 0.489, -3.69" in one and "0.720" in one
    # a config without instance grouping says so, rather than "0 instances"
    bare = QueryResult(qs, mask, np.zeros(n, np.float32), np.zeros(n, np.float32))
    assert "instances=off" in repr(bare)


@pytest.mark.parametrize("cls", ["QueryResult", "Instance"])
def test_every_field_of_a_result_is_documented(cls):
    """QueryResult's docstring listed 4 of its 11 fields (not ``instances``, ``timings``
    or ``map_source``) and none of its properties; Instance's listed none."""
    import dataclasses
    import inspect

    from quash_plugins.core import types

    klass = getattr(types, cls)
    doc = inspect.getdoc(klass)
    attributes = doc.split("Attributes\n----------\n", 1)[1]
    documented = set()
    for line in attributes.splitlines():
        if line and not line.startswith(" "):
            documented |= {n.strip() for n in line.split(",")}
    names = {f.name for f in dataclasses.fields(klass)}
    names |= {
        n
        for n, v in vars(klass).items()
        if isinstance(v, property) and not n.startswith("_") and n != "size"
    }
    missing = names - documented
    assert not missing, f"{cls} does not document {sorted(missing)}"
    assert not documented - names, sorted(documented - names)


@pytest.mark.parametrize("names", ["chair", np.array("chair"), np.array([["chair", "sofa"]])])
def test_label_names_that_are_not_one_list_of_names_are_refused(names):
    """LatentMap(..., label_names="chair") iterated the string: the map's labels were
    'c', 'h', 'a', 'i', 'r', with nothing said, and evaluation scored label 'c'."""
    from quash_plugins.core.errors import MapFormatError
    from quash_plugins.core.types import LatentMap

    emb = np.eye(3, dtype=np.float32)
    with pytest.raises(MapFormatError, match=r"Field 'label_names' must be a list of names") as e:
        LatentMap(emb, labels=np.zeros(3, dtype=int), label_names=names)
    if np.ndim(names) == 0:
        assert "label_names=['chair']" in str(e.value)
    # a list, a tuple or a 1-D array of names is a label list
    for ok in (["chair"], ("chair",), np.array(["chair"])):
        assert LatentMap(emb, labels=np.zeros(3, dtype=int), label_names=ok).label_names == [
            "chair"
        ]


def test_embeddings_numpy_cannot_read_are_refused_naming_the_field_and_the_fix():
    """LatentMap(torch_features) raised a bare TypeError "Cannot interpret
    'torch.float32' as a data type", naming neither the field nor what to give."""
    from quash_plugins.core.errors import MapFormatError
    from quash_plugins.core.types import LatentMap

    class Tensor:  # what a torch tensor shows LatentMap: a shape and a foreign dtype
        shape = (5, 8)
        dtype = "torch.float32"

    with pytest.raises(MapFormatError, match=r"Field 'embeddings' is a Tensor of torch\.float32"):
        LatentMap(Tensor())
    torch = pytest.importorskip("torch")
    with pytest.raises(MapFormatError, match=r"\.detach\(\)\.cpu\(\)\.numpy\(\)"):
        LatentMap(torch.zeros(5, 8))
    assert LatentMap(torch.zeros(5, 8).detach().cpu().numpy()).dim == 8


def test_a_maps_repr_is_one_line_naming_what_it_carries():
    """print(lmap) in a notebook gave numpy's summary of every array (some thirty lines
    for a scene); it is now one line: describe(), then what else the map carries."""
    import numpy as np

    from quash_plugins.core.types import LatentMap

    rng = np.random.default_rng(0)
    lmap = LatentMap(
        rng.normal(size=(40, 6)).astype(np.float32),
        kind="voxels",
        positions=rng.uniform(size=(40, 3)).astype(np.float32),
        labels=rng.integers(0, 2, 40),
        label_names=["chair", "sofa"],
        voxel_size=0.05,
        source={"path": "room.npz", "adapter": "npz"},
    )
    text = repr(lmap)
    assert "\n" not in text
    assert text == (
        f"LatentMap({lmap.describe()}; positions, labels, 2 label names, voxel_size=0.05)"
    )
    bare = LatentMap(np.eye(3, dtype=np.float32))
    assert repr(bare) == f"LatentMap({bare.describe()}; embeddings only)"
    bare.voxel_size = "fine"  # repr never raises, whatever a field holds
    assert "voxel_size='fine'" in repr(bare)


@pytest.mark.parametrize("size", ["0.1", -1.0, 0, float("nan"), True])
def test_a_voxel_size_that_is_no_positive_number_is_refused(size):
    """voxel_size="0.1" or -1 was kept as given (the viewer and instance radii read it)."""
    import numpy as np

    from quash_plugins.core.errors import MapFormatError
    from quash_plugins.core.types import LatentMap

    with pytest.raises(MapFormatError) as err:
        LatentMap(np.eye(3, dtype=np.float32), voxel_size=size)
    assert "Field 'voxel_size'" in str(err.value) and "positive number of metres" in str(err.value)
    assert LatentMap(np.eye(3, dtype=np.float32), voxel_size=np.float32(0.05)).voxel_size == (
        float(np.float32(0.05))
    )


def test_a_grid_index_of_whole_floats_is_read_as_cells_and_fractions_are_refused():
    import numpy as np

    from quash_plugins.core.errors import MapFormatError
    from quash_plugins.core.types import LatentMap

    cells = np.array([[0, 0, 0], [1, 0, 0], [5, 2, 1]])
    lmap = LatentMap(np.eye(3, dtype=np.float32), grid_index=cells.astype(np.float64))
    assert lmap.grid_index.dtype == np.int64 and np.array_equal(lmap.grid_index, cells)
    with pytest.raises(MapFormatError, match="whole cell indices; got float64 with fractions"):
        LatentMap(np.eye(3, dtype=np.float32), grid_index=cells + 0.5)
    with pytest.raises(MapFormatError, match="np.floor"):
        LatentMap(np.eye(3, dtype=np.float32), grid_index=np.full((3, 3), "a"))
