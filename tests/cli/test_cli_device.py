"""A device that is not on this machine is refused before the map is read, naming the
option (``--device``) or the config file and its field; auto and cpu go through."""

from __future__ import annotations

import argparse

import pytest

from quash_plugins.cli._config_opts import apply_runtime_options, check_devices_present
from quash_plugins.cli.main import main
from quash_plugins.core.config import QuashConfig
from quash_plugins.core.errors import ConfigError, UsageError
from quash_plugins.engine.device import device_unavailable
from quash_plugins.engine.pipeline import Quash

torch = pytest.importorskip("torch")


class _Read(Exception):
    """Raised by the spy in place of reading the map."""


@pytest.fixture
def reads(monkeypatch):
    """Every map read, stopped at once: a refused device must come before the first."""
    seen: list[str] = []

    def spy(self, source, *args, **kwargs):
        seen.append(str(source))
        raise _Read(str(source))

    monkeypatch.setattr(Quash, "read_map", spy)
    return seen


def _gpus(monkeypatch, n: int) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: n > 0)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: n)


def _no_mps(monkeypatch) -> None:
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: False)


@pytest.mark.parametrize("device", ["cuda", "cuda:0", "cuda:2"])
def test_cuda_flag_without_a_gpu_is_refused_before_the_map_is_read(
    device, monkeypatch, reads, tmp_path, capsys
):
    _gpus(monkeypatch, 0)
    rc = main(["query", str(tmp_path / "map.npz"), "chair", "--device", device])
    err = capsys.readouterr().err
    assert rc == 2 and reads == []
    assert f"--device {device}:" in err and "no CUDA GPU" in err
    assert "--device auto" in err and "--device cpu" in err


def test_cuda_index_beyond_the_gpus_is_refused(monkeypatch, reads, tmp_path, capsys):
    _gpus(monkeypatch, 2)
    rc = main(["query", str(tmp_path / "map.npz"), "chair", "--device", "cuda:2"])
    err = capsys.readouterr().err
    assert rc == 2 and reads == []
    assert "--device cuda:2:" in err and "2 CUDA GPU(s)" in err and "numbered from 0" in err
    assert device_unavailable("cuda:1") is None  # the last one there is taken
    assert device_unavailable("cuda") is None


def test_mps_without_mps_is_refused_for_a_torch_encoder(monkeypatch, reads, tmp_path, capsys):
    _no_mps(monkeypatch)
    rc = main(["expand", "chair", "--device", "mps"])
    err = capsys.readouterr().err
    assert rc == 2 and "--device mps:" in err and "no Apple MPS" in err
    # an encoder that takes no device never runs on mps: nothing is refused
    cfg = QuashConfig.from_dict({"encoder": "bag-of-words", "device": "mps"})
    check_devices_present(cfg)
    # nor for one whose section names its own device
    cfg = QuashConfig.from_dict({"encoder": {"name": "minilm", "device": "cpu"}, "device": "mps"})
    check_devices_present(cfg)
    with pytest.raises(ConfigError, match="device: 'mps': torch sees no Apple MPS"):
        check_devices_present(QuashConfig.from_dict({"encoder": "minilm", "device": "mps"}))


def test_a_config_files_device_is_refused_naming_the_file_and_field(
    monkeypatch, reads, tmp_path, capsys
):
    _gpus(monkeypatch, 0)
    cfg = tmp_path / "q.yaml"
    cfg.write_text("name: q\nencoder: minilm\ndevice: cuda\n", encoding="utf-8")
    rc = main(["query", str(tmp_path / "map.npz"), "chair", "-c", str(cfg)])
    err = capsys.readouterr().err
    assert rc == 1 and reads == []
    assert f"{cfg}:3: device: 'cuda':" in err and "no CUDA GPU" in err
    assert "--device cpu" in err

    # a section's own device: the section's line and field
    cfg.write_text("name: q\nencoder: {name: minilm, device: cuda:1}\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"q\.yaml:2: encoder\.device: 'cuda:1'"):
        check_devices_present(QuashConfig.from_yaml(cfg))

    # --device cpu overrides the file, and the map is read
    cfg.write_text("name: q\nencoder: minilm\ndevice: cuda\n", encoding="utf-8")
    with pytest.raises(_Read):
        main(["--debug", "query", "map.npz", "chair", "-c", str(cfg), "--device", "cpu"])
    assert reads == ["map.npz"]


@pytest.mark.parametrize("device", ["auto", "cpu", "AUTO"])
def test_auto_and_cpu_go_through_without_asking_torch(device, monkeypatch, reads):
    def asked():
        raise AssertionError("torch.cuda consulted for auto or cpu")

    monkeypatch.setattr(torch.cuda, "is_available", asked)
    monkeypatch.setattr(torch.cuda, "device_count", asked)
    cfg = apply_runtime_options(QuashConfig.default(), argparse.Namespace(device=device))
    assert cfg.device == device.lower()
    with pytest.raises(_Read):
        main(["--debug", "query", "map.npz", "chair", "--device", device])
    assert reads == ["map.npz"]


def test_present_devices_go_through(monkeypatch):
    _gpus(monkeypatch, 1)
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: True)
    for device in ("cuda", "cuda:0", "mps"):
        cfg = apply_runtime_options(QuashConfig.default(), argparse.Namespace(device=device))
        assert cfg.device == device
    with pytest.raises(UsageError, match="1 CUDA GPU"):
        apply_runtime_options(QuashConfig.default(), argparse.Namespace(device="cuda:1"))
