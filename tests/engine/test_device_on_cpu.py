"""The GPU code path (engine.device), run on the CPU: the plan, the torch executors, the
device map (resident and streamed), the pipeline's device routing, and the fused Triton
kernel under ``TRITON_INTERPRET=1``.

Everything is compared with scikit-learn's decision_function on float16 maps.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from sklearn.metrics.pairwise import cosine_similarity

from quash_plugins import registry
from quash_plugins.core.errors import MapFormatError
from quash_plugins.core.types import LatentMap
from quash_plugins.engine import classify_local
from quash_plugins.engine.device import (
    DeviceMap,
    DeviceSvmPlan,
    build_plan,
    classify_on_device,
    reference_scores,
    svm_scores_torch,
)

torch = pytest.importorskip("torch")

D = 40
ROOT = Path(__file__).resolve().parents[2]


def _svms(rng):
    X = rng.standard_normal((30, D)).astype(np.float32)
    X /= np.linalg.norm(X, axis=1, keepdims=True)
    y = (np.arange(30) < 8).astype(int)
    return (
        [
            registry.create("classifiers", "svm-rbf").fit(X, y),
            registry.create("classifiers", "svm-rbf", gamma=3.0, C=10.0).fit(X, np.roll(y, 3)),
            registry.create("classifiers", "svm-cosine").fit(X, y),
            registry.create("classifiers", "svm-cosine", kernel="linear-cosine").fit(X, y),
            # fitted for the torch back end: the pass, not the classifier, picks the device
            registry.create("classifiers", "svm-cosine", distance="plain", backend="torch").fit(
                X, y
            ),
        ],
        X,
        y,
    )


def _map16(rng, n=700):
    E = rng.standard_normal((n, D)) * rng.uniform(0.02, 0.3, (n, 1))
    E[::13] = 0.0
    return E.astype(np.float16)


def sklearn_decision(clf, X):
    """scikit-learn's SVC decision values on float64 rows ``X`` (kernel built here)."""
    if clf._who == "svm-rbf":
        return clf.svc_.decision_function(X)
    cos = cosine_similarity(X, clf.X_fit_.astype(np.float64))
    if clf.kernel == "linear-cosine":
        return clf.svc_.decision_function(cos)
    d = np.maximum(1.0 - cos, 0.0)
    return clf.svc_.decision_function(np.exp(-clf.gamma_ * (d**2 if clf._power == 2 else d)))


def _sklearn(clfs, E, normalize):
    X = E.astype(np.float64)
    if normalize:
        n = np.linalg.norm(X, axis=1, keepdims=True)
        X = np.divide(X, n, out=np.zeros_like(X), where=n > 0)
    return np.stack([sklearn_decision(c, X) for c in clfs], axis=1)


@pytest.mark.parametrize("normalize", [False, True])
def test_plan_and_torch_fallback_match_sklearn(normalize):
    rng = np.random.default_rng(0)
    clfs, _, _ = _svms(rng)
    E = _map16(rng)
    plan = build_plan(clfs).svm
    sk = _sklearn(clfs, E, normalize)
    np.testing.assert_allclose(reference_scores(plan, E, normalize), sk, atol=1e-6)
    dp = DeviceSvmPlan.build(plan, "cpu")
    out = torch.empty((len(clfs), len(E)))
    svm_scores_torch(torch.from_numpy(E), dp, normalize, out, chunk_rows=97)
    np.testing.assert_allclose(out.numpy().T, sk, atol=1e-5)


def test_split_halves_hold_v_to_float32_accuracy():
    clfs, _, _ = _svms(np.random.default_rng(1))
    plan = build_plan(clfs).svm
    hi, lo = plan.halves()
    err = np.abs(hi.astype(np.float64) + lo.astype(np.float64) - plan.V).max()
    assert err <= 2.0**-21 * np.abs(plan.V).max()


@pytest.mark.parametrize("normalize", [False, True])
@pytest.mark.parametrize("budget", [None, 1000])  # resident, streamed
def test_classify_on_device_cpu_matches_the_cpu_pass(normalize, budget):
    rng = np.random.default_rng(2)
    clfs, X, y = _svms(rng)
    rules = [
        registry.create("classifiers", name, **params).fit(X, y)
        for name, params in [
            ("contrast", {}),
            ("nearest-sample", {"k": 2}),
            ("lerf-relevancy", {}),
            ("cosine-threshold", {}),
            ("label-argmax", {}),
            ("label-argmax", {"ties": "earlier"}),  # no declared margin: reduced on the host
            ("sklearn", {"estimator": "sklearn.linear_model.LogisticRegression"}),
        ]
    ]
    allc = clfs + rules
    lm = LatentMap(_map16(rng), normalize=normalize)
    dm = DeviceMap(lm, "cpu", chunk_bytes=200 * D * 2, budget_bytes=budget)
    assert dm.resident == (budget is None)
    got, obs = classify_on_device(dm, allc, use_triton=False)
    ref, ref_obs = classify_local(lm, allc)
    np.testing.assert_array_equal(obs, ref_obs)
    for g, r in zip(got, ref):
        np.testing.assert_allclose(g[obs], r[obs], atol=1e-5)


@pytest.mark.parametrize("k", [1, 2, 9])  # 9: more than either side's columns
@pytest.mark.parametrize("use_negatives", [True, False])
@pytest.mark.parametrize("temperature", [None, 10.0])
def test_the_torch_margin_is_the_numpy_reference(k, use_negatives, temperature):
    """The device pass's torch reduction of a declared cosine rule gives what the rule's
    own numpy reduction (``CosineMargin.apply``, the reference) gives, ties included."""
    from quash_plugins.core.kernels import CosineMargin
    from quash_plugins.engine.device._torch_svm import reduce_margin

    rng = np.random.default_rng(k)
    c = rng.uniform(-1, 1, (64, 7)).astype(np.float32)
    c[:8, 1] = c[:8, 0]  # tied positives
    for positives in (1, 3, 7):  # 7: no negative column
        margin = CosineMargin(positives, k, use_negatives, temperature, offset=0.25)
        got = reduce_margin(margin, torch.from_numpy(c)).numpy()
        assert got.dtype == np.float32 and got.shape == (64,)
        np.testing.assert_allclose(got, margin.apply(c), rtol=0, atol=1e-6)


def test_the_pipeline_routes_queries_to_the_device_pass(monkeypatch):
    """``device`` picks the pass: here the device pass on torch's CPU. query_many with a
    refinement pass runs on it, reusing one upload of the map, and gives the CPU pass's
    results."""
    from quash_plugins import Quash
    from quash_plugins.encoders import TableEncoder
    from quash_plugins.engine import device as device_pkg

    rng = np.random.default_rng(5)
    words = ["chair", "table", "sofa", "other", "background", "nothing"]
    T = rng.normal(size=(len(words), D))
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    labels = rng.integers(0, 3, 4000)
    E = (T[labels] + 0.6 * rng.normal(size=(4000, D))) * rng.uniform(0.2, 2, (4000, 1))
    E[:40] = 0
    lmap = LatentMap(E.astype(np.float16), normalize=True)

    def quash(device):
        return Quash(
            TableEncoder(table=dict(zip(words, T.tolist()))),
            classifier=registry.create("classifiers", "svm-rbf", C=10.0),
            refine={"n_positives": 50, "n_negatives": 200},
            instances=None,
            device=device,
        )

    reference = quash("cpu").query_many(lmap, ["chair", "table"])
    uploads, passes = [], []
    real_map, real_pass = device_pkg.DeviceMap, device_pkg.classify_on_device
    monkeypatch.setattr(device_pkg, "pass_device", lambda device: "cpu")
    monkeypatch.setattr(
        device_pkg, "device_map", lambda m, d, chunk_bytes: uploads.append(d) or real_map(m, d)
    )
    monkeypatch.setattr(
        device_pkg, "classify_on_device", lambda *a, **k: passes.append(1) or real_pass(*a, **k)
    )
    got = quash("cuda").query_many(lmap, ["chair", "table"])
    assert uploads == ["cpu", "cpu"] and len(passes) == 2  # the first pass and refinement
    for g, r in zip(got, reference):
        assert g.queryset.provenance["refine"]["applied"]
        close = np.abs(r.scores) < 1e-4  # a hair from the threshold may flip
        np.testing.assert_array_equal(g.mask[~close], r.mask[~close])
        np.testing.assert_allclose(g.scores, r.scores, atol=1e-5)


def test_the_device_map_cache_uploads_once_per_live_map():
    from quash_plugins.engine.device import device_map, release_device_maps

    lmap = LatentMap(_map16(np.random.default_rng(6)))
    first = device_map(lmap, "cpu")
    assert device_map(lmap, "cpu") is first
    assert device_map(LatentMap(lmap.embeddings), "cpu") is not first  # another map
    release_device_maps()
    assert device_map(lmap, "cpu") is not first


def test_unsupported_and_missing_devices_are_refused():
    from quash_plugins import Quash
    from quash_plugins.core.errors import ConfigError, QuashError
    from quash_plugins.encoders import TableEncoder
    from quash_plugins.engine.device import pass_device

    enc = TableEncoder(table={"chair": [1, 0], "other": [0, 1], "background": [1, 1],
                              "nothing": [1, -1]})  # fmt: skip
    lmap = LatentMap(np.eye(2, dtype=np.float32))
    with pytest.raises(ConfigError, match="'tpu' is not a supported device; use one of auto"):
        Quash(enc, device="tpu", instances=None)  # refused when built, before any query
    for bad in ("cuda:x", "cpu:0", "gpu", "tpu"):
        with pytest.raises(ConfigError):
            pass_device(bad)
    assert pass_device("cpu") is None and pass_device("mps") is None
    if not torch.cuda.is_available():
        with pytest.raises(QuashError, match="no CUDA GPU on this machine; use device: cpu"):
            Quash(enc, device="cuda", instances=None).query(lmap, "chair")
        assert pass_device("auto") is None


@pytest.mark.parametrize("gpus", [0, 2])
@pytest.mark.parametrize("device", ["cuda", "cuda:0", "cuda:1", "cuda:2"])
def test_the_pass_refuses_a_device_exactly_when_the_cli_check_does(device, gpus, monkeypatch):
    """pass_device and device_unavailable run one check: the pass raises the CLI's reason."""
    from quash_plugins.core.errors import QuashError
    from quash_plugins.engine.device import device_unavailable, pass_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: gpus > 0)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: gpus)
    why = device_unavailable(device)
    assert (why is None) == (gpus == 2 and device != "cuda:2")
    if why is None:
        assert pass_device(device) == device
    else:
        with pytest.raises(QuashError) as err:
            pass_device(device)
        assert f"device {device!r}: {why}; use device: cpu" in str(err.value)


@pytest.mark.parametrize("budget", [None, 1000])
def test_device_map_names_the_nan_row(budget):
    E = _map16(np.random.default_rng(3))
    E[333, 3] = np.nan
    clfs, _, _ = _svms(np.random.default_rng(3))
    with pytest.raises(MapFormatError, match="row 333"):
        dm = DeviceMap(LatentMap(E), "cpu", chunk_bytes=200 * D * 2, budget_bytes=budget)
        classify_on_device(dm, clfs[:1], use_triton=False)


def test_device_map_uploads_as_stored_and_never_normalises():
    E = _map16(np.random.default_rng(4))
    dm = DeviceMap(LatentMap(E, normalize=True), "cpu")
    assert dm.emb.dtype == torch.float16
    np.testing.assert_array_equal(dm.emb.numpy(), E)
    np.testing.assert_array_equal(dm.observed, (E.astype(np.float32) ** 2).sum(1) > 0)


_TRITON_SCRIPT = textwrap.dedent(
    """
    import sys
    import numpy as np, torch
    sys.path.insert(0, {root!r})
    from quash_plugins import registry
    from quash_plugins.engine.device import DeviceSvmPlan, build_plan, launch
    sys.path.insert(0, {tests!r})
    from test_device_on_cpu import sklearn_decision
    rng = np.random.default_rng(0)
    D = 40
    X = rng.standard_normal((30, D)).astype(np.float32)
    X /= np.linalg.norm(X, axis=1, keepdims=True)
    y = (np.arange(30) < 8).astype(int)
    clfs = [
        registry.create("classifiers", "svm-rbf").fit(X, y),
        registry.create("classifiers", "svm-rbf", gamma=3.0, C=10.0).fit(X, np.roll(y, 3)),
        registry.create("classifiers", "svm-cosine").fit(X, y),
        registry.create("classifiers", "svm-cosine", kernel="linear-cosine").fit(X, y),
    ]
    E = (rng.standard_normal((203, D)) * rng.uniform(0.02, 0.3, (203, 1))).astype(np.float16)
    E[::13] = 0
    worst = {{}}
    for subset in ([0], [0, 1], [0, 1, 2, 3]):
        cl = [clfs[i] for i in subset]
        dp = DeviceSvmPlan.build(build_plan(cl).svm, "cpu")
        for normalize in (False, True):
            Xin = E.astype(np.float64)
            if normalize:
                n = np.linalg.norm(Xin, axis=1, keepdims=True)
                Xin = np.divide(Xin, n, out=np.zeros_like(Xin), where=n > 0)
            sk = np.stack([sklearn_decision(c, Xin) for c in cl], 1)
            for mode in (0, 1, 2):
                out = torch.empty((len(cl), len(E)))
                sq = torch.empty(len(E))
                launch(torch.from_numpy(E), dp, normalize, out, sq, mode=mode)
                err = float(np.abs(out.numpy().T - sk).max())
                worst[mode] = max(worst.get(mode, 0.0), err)
                ref_sq = (E.astype(np.float64) ** 2).sum(1)
                assert np.abs(sq.numpy() - ref_sq).max() < 1e-5
    print("WORST", worst[0], worst[1], worst[2])
    """
)


def test_triton_kernel_under_the_interpreter_matches_sklearn(tmp_path):
    pytest.importorskip("triton")
    script = tmp_path / "run.py"
    script.write_text(_TRITON_SCRIPT.format(root=str(ROOT), tests=str(Path(__file__).parent)))
    env = {**os.environ, "TRITON_INTERPRET": "1"}
    res = subprocess.run(
        [sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=600
    )
    assert res.returncode == 0, res.stderr[-3000:]
    line = [ln for ln in res.stdout.splitlines() if ln.startswith("WORST")][-1]
    split, single, f32 = (float(v) for v in line.split()[1:])
    assert split < 1e-5  # mode 0: float16 map, V in hi + lo halves
    assert f32 < 1e-5  # mode 2: tf32x3
    assert single < 1e-3  # mode 1: V in float16 only (the bound)


def _run_benchmark(script: str, args: str, **env: str) -> subprocess.CompletedProcess:
    """Run ``benchmarks/<script> <args>`` with the project on the path; it must succeed."""
    res = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / script), *args.split()],
        env={**os.environ, "PYTHONPATH": str(ROOT), **env},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    return res


def test_the_gpu_benchmark_runs_as_a_dry_run_on_the_cpu():
    """benchmarks/bench_gpu.py end to end at toy sizes (Triton interpreted): every row of
    its table is produced and its accuracy lines hold."""
    pytest.importorskip("triton")
    res = _run_benchmark(
        "bench_gpu.py",
        "--device cpu --rows 3000 --dim 64 --sv 16 --stack 3 --reps 2 --host-rows 1500 "
        "--check-rows 3000 --no-autotune",
        TRITON_INTERPRET="1",
    )
    table = [ln for ln in res.stdout.splitlines() if ln.startswith("| ")]
    assert len(table) == 1 + 12 and not any("skipped" in ln for ln in table), res.stdout
    accuracy = [ln for ln in res.stdout.splitlines() if ln.startswith("max |diff|")][0]
    errors = dict(part.split(": ") for part in accuracy.split(" rows: ")[1].split(", "))
    assert float(errors["mode 0"]) < 1e-5 and float(errors["mode 1"]) < 1e-3
    assert "targets: 1 query" in res.stdout


def test_the_classify_stage_benchmark_runs():
    res = _run_benchmark("bench_classify_stage.py", "--rows 3000 --dim 32 --reps 1")
    rows = [ln for ln in res.stdout.splitlines() if ln.startswith("| float")]
    assert len(rows) == 4 and all(ln.count("x |") == 3 for ln in rows), res.stdout
