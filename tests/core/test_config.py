from __future__ import annotations

from pathlib import Path

import pytest

from quash_plugins import Quash, QuashConfig
from quash_plugins.core.errors import ConfigError, PluginError, QuashError


def test_yaml_round_trip_and_relative_paths(tiny_world):
    cfg = QuashConfig.from_yaml(tiny_world["config"])
    assert cfg.name == "vlmaps-contrast"
    assert cfg.encoder.name == "table"
    # the table path is resolved against the config's folder
    assert cfg.encoder.params["file"] == str(tiny_world["table"].resolve())
    assert cfg.negatives == ["other", "background", "nothing"]
    again = QuashConfig.from_dict(cfg.to_dict())
    assert again.to_dict() == cfg.to_dict()


def test_unknown_key_names_file_line_and_suggestion(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("name: x\nclassifer: svm-rbf\n")
    with pytest.raises(ConfigError) as err:
        QuashConfig.from_yaml(p)
    msg = str(err.value)
    assert f"{p}:2:" in msg and "'classifer'" in msg and "Did you mean 'classifier'" in msg


def test_vlmaps_own_map_config_given_as_the_config_says_what_it_is(tmp_path, capsys):
    """``quash query MAP chair -c config/map_config/vlmaps.yaml`` (VLMaps' map config, the
    one config a VLMaps user has) read "unknown key 'map_type' ... Did you mean
    'adapter'?"; it now says what the file is and where its cell size goes."""
    from quash_plugins.cli.main import main

    p = tmp_path / "vlmaps.yaml"  # the layout of VLMaps' config/map_config/vlmaps.yaml
    p.write_text(
        "map_type: vlmap\npose_info:\n  pose_type: mobile_base\n  camera_height: 1.5\n"
        "cam_calib_mat: [540, 0, 540, 0, 540, 360, 0, 0, 1]\n"
        "grid_size: 1000\ncell_size: 0.05\ndepth_sample_rate: 100\n"
    )
    with pytest.raises(ConfigError) as err:
        QuashConfig.from_yaml(p)
    msg = " ".join(str(err.value).split())
    assert msg.startswith(f"{p}:1: this is VLMaps' map config"), msg
    assert "(it has cell_size, grid_size, map_type, pose_info)" in msg
    assert "-o cs=0.05" in msg and "Did you mean" not in msg
    assert main(["expand", "chair", "-c", str(p)]) == 1
    assert "this is VLMaps' map config" in " ".join(capsys.readouterr().err.split())
    # a QuASH config with one misspelt key is not taken for one
    p.write_text("encoder: minilm\ncel_size: 0.05\n")
    with pytest.raises(ConfigError, match="unknown key 'cel_size'"):
        QuashConfig.from_yaml(p)


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("classifier: svm-rbf\nC: 2\n", "classifier: {name: svm-rbf, C: ...}"),
        # the default classifier's, when the config names none
        ("name: x\nk: 3\n", "classifier: {name: nearest-sample, k: ...}"),
        ("heuristic: {name: taxonomy}\nn_synonyms: 5\n", "heuristic: {name: taxonomy, n_synonyms"),
    ],
)
def test_a_plugin_parameter_written_at_the_top_says_which_section_takes_it(tmp_path, text, where):
    p = tmp_path / "c.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError) as err:
        QuashConfig.from_yaml(p)
    msg = " ".join(str(err.value).split())
    assert msg.startswith(f"{p}:{text.count(chr(10))}: unknown key") and where in msg, msg


def test_a_top_level_key_no_plugin_takes_gets_no_section_hint(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("classifier: svm-rbf\nwibble: 2\n")
    with pytest.raises(ConfigError) as err:
        QuashConfig.from_yaml(p)
    assert "unknown key 'wibble'" in str(err.value) and "section" not in str(err.value)


def test_a_misspelt_name_of_a_plugin_section_is_suggested(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("encoder: {nam: minilm}\n")
    with pytest.raises(ConfigError) as err:
        QuashConfig.from_yaml(p)
    assert "Did you mean 'name' for 'nam'?" in str(err.value), err.value


def test_malformed_yaml_names_file_and_line(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("name: x\nencoder: {name: table\nclassifier: svm-rbf\n")
    with pytest.raises(ConfigError) as err:
        QuashConfig.from_yaml(p)
    assert str(p) in str(err.value) and "malformed YAML" in str(err.value)
    assert ":3:" in str(err.value) or ":2:" in str(err.value)


def test_wrong_types_are_rejected(tmp_path):
    with pytest.raises(ConfigError, match="'threshold' must be a float"):
        QuashConfig.from_dict({"threshold": "high"})
    with pytest.raises(ConfigError, match="'cache' must be true or false"):
        QuashConfig.from_dict({"cache": "yes"})
    with pytest.raises(ConfigError, match="'negatives' must be a list"):
        QuashConfig.from_dict({"negatives": "other"})
    with pytest.raises(ConfigError, match="plugin name or a mapping with 'name'"):
        QuashConfig.from_dict({"classifier": {"C": 1}})


def test_unaccepted_plugin_parameter_names_the_file(tiny_world, tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text(
        f"encoder: {{name: table, file: {tiny_world['table']}}}\n"
        "classifier: {name: svm-rbf, C: 1.0, kernel: poly}\n"
    )
    with pytest.raises(ConfigError) as err:
        Quash.from_config(p)
    msg = str(err.value)
    assert str(p) in msg and "'kernel'" in msg and "Accepted: C, gamma" in msg


@pytest.mark.parametrize(
    ("lines", "line", "error", "words"),
    [
        # the parameter's own line, in block and in flow style
        (
            ["encoder: {name: table, file: T}", "classifier:", "  name: svm-rbf", "  gammma: 2"],
            4,
            ConfigError,
            "does not accept parameter 'gammma'",
        ),
        (
            [
                "encoder: {name: table, file: T}",
                "name: x",
                "classifier: {name: svm-rbf, gammma: 2}",
            ],
            3,
            ConfigError,
            "does not accept parameter 'gammma'",
        ),
        # the name's line, under its section
        (
            ["encoder: {name: table, file: T}", "heuristic:", "  name: taxonomyy"],
            3,
            PluginError,
            "Heuristic 'taxonomyy' is not registered",
        ),
        (["name: x", "encoder: minilmm"], 2, PluginError, "Encoder 'minilmm' is not registered"),
    ],
)
def test_a_plugin_error_names_the_line_of_the_entry(
    tiny_world, tmp_path, lines, line, error, words
):
    """An unknown plugin or parameter names the config file's line, as an unknown key
    does: ``c.yaml:4: classifier: ... 'gammma'``, not only the file and the section."""
    p = tmp_path / "c.yaml"
    p.write_text("\n".join(lines).replace("file: T", f"file: {tiny_world['table']}") + "\n")
    with pytest.raises(error) as err:
        Quash.from_config(p)
    msg = str(err.value)
    assert msg.startswith(f"{p}:{line}: ") and words in msg, msg
    assert msg.count(str(p)) == 1, msg


def test_unknown_plugin_in_config(tiny_world):
    with pytest.raises(PluginError, match="Heuristic 'llmm' is not registered"):
        Quash.from_config(
            {"encoder": {"name": "table", "file": str(tiny_world["table"])}, "heuristic": "llmm"}
        )


def test_unsupported_devices_are_refused_everywhere(tiny_world, tmp_path, capsys):
    from quash_plugins.cli.main import main
    from quash_plugins.core import registry

    p = tmp_path / "c.yaml"
    p.write_text("name: x\ndevice: tpu\n")
    with pytest.raises(ConfigError) as err:
        QuashConfig.from_yaml(p)
    assert f"{p}:2:" in str(err.value) and "'tpu'" in str(err.value) and "cuda:N" in str(err.value)
    assert QuashConfig.from_dict({"device": "CUDA:1"}).device == "cuda:1"
    rc = main(
        ["query", str(tiny_world["map"]), "chair", "-c", str(tiny_world["config"])]
        + ["--device", "tpu"]
    )
    assert rc == 2 and "--device: 'tpu'" in capsys.readouterr().err
    for kind, name in (
        ("encoders", "minilm"),
        ("encoders", "open-clip"),
        ("classifiers", "svm-rbf"),
    ):
        params = {"device": "tpu"} | ({"model": "ViT-B-32"} if name == "open-clip" else {})
        with pytest.raises(QuashError, match="tpu"):
            registry.create(kind, name, **params)


def _adapter_options(tmp_path, adapter: str):
    """The folder of ``cfg/c.yaml`` holding ``adapter: ADAPTER``, and the adapter's
    options as the config reads them."""
    folder = tmp_path / "cfg"
    folder.mkdir(exist_ok=True)
    p = folder / "c.yaml"
    p.write_text(f"name: x\nadapter: {adapter}\n")
    return folder, QuashConfig.from_yaml(p).adapter.params


def test_an_adapters_points_file_is_resolved_against_the_config_folder(tmp_path):
    """The openscene adapter's ``points`` travels with its config like every path option."""
    folder, params = _adapter_options(tmp_path, "{name: openscene, points: scene_vh_clean_2.pth}")
    assert params["points"] == str((folder / "scene_vh_clean_2.pth").resolve())


def _read_from_elsewhere(tmp_path, monkeypatch, files: dict, text: str):
    """Write ``files`` and the config ``text`` into tmp_path/cfg, and read the config
    from another folder: ``(config, its folder)``."""
    folder = tmp_path / "cfg"
    folder.mkdir()
    for name, content in files.items():
        (folder / name).write_text(content, encoding="utf-8")
    (folder / "c.yaml").write_text(text)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    return QuashConfig.from_yaml(folder / "c.yaml"), folder


def test_unlisted_and_map_negatives_files_are_resolved_against_the_config_folder(
    tmp_path, monkeypatch
):
    """A file of names given as a label list's ``unlisted`` or as ``map_negatives``'
    ``vocabulary`` travels with its config, as docs/config.md says of every path (run from
    another folder, both were looked up in the current folder: 'file not found')."""
    from quash_plugins.core import registry

    cfg, folder = _read_from_elsewhere(
        tmp_path,
        monkeypatch,
        {"names.txt": "fireplace\npiano\n"},
        "heuristic: {name: combine, synonyms: {name: taxonomy, unlisted: names.txt},\n"
        "            antonyms: {name: label-list, unlisted: vocabulary}}\n"
        "map_negatives: {n: 3, vocabulary: names.txt}\n",
    )
    names = str((folder / "names.txt").resolve())
    assert cfg.map_negatives["vocabulary"] == names
    assert cfg.heuristic.params["synonyms"]["unlisted"] == names
    assert cfg.heuristic.params["antonyms"]["unlisted"] == "vocabulary"  # the shipped list
    taxonomy = registry.create("heuristics", "taxonomy", unlisted=names)
    assert taxonomy._unlisted == {"fireplace", "piano"}
    again = QuashConfig.from_dict(cfg.to_dict())
    assert again.map_negatives == cfg.map_negatives


def test_a_template_file_of_the_templates_heuristic_is_resolved_against_the_config_folder(
    tmp_path, monkeypatch
):
    """``heuristic: {name: templates, templates: mine.txt}`` reads mine.txt beside the
    config, as the ``prompt_templates`` setting's ``templates`` does (from another folder
    it was 'Prompt-template file not found: mine.txt ... Fix the path'); a list's name and
    a list stay as they are."""
    from quash_plugins.core import registry

    cfg, folder = _read_from_elsewhere(
        tmp_path,
        monkeypatch,
        {"mine.txt": "a photo of a {}.\nthe {} in a room.\n"},
        "heuristic: {name: combine, synonyms: {name: templates, templates: mine.txt},\n"
        "            antonyms: {name: templates, templates: vlmaps-or-default}}\n",
    )
    mine = cfg.heuristic.params["synonyms"]["templates"]
    assert mine == str((folder / "mine.txt").resolve())
    assert cfg.heuristic.params["antonyms"]["templates"] == "vlmaps-or-default"
    h = registry.create("heuristics", "templates", templates=mine)
    assert list(h.prompt_templates["templates"]) == ["a photo of a {}.", "the {} in a room."]
    listed = QuashConfig.from_dict({"heuristic": {"name": "templates", "templates": ["{}"]}})
    assert listed.heuristic.params["templates"] == ["{}"]


def test_an_adapters_images_folder_is_resolved_against_the_config_folder(tmp_path):
    """The image-features adapter's ``images`` travels with its config, as ``points`` does:
    ``images: ../rgb`` in ``cfg/c.yaml`` was read from the working folder."""
    _, params = _adapter_options(tmp_path, "{name: image-features, images: ../rgb}")
    assert Path(params["images"]).resolve() == (tmp_path / "rgb").resolve()


def test_an_adapters_label_names_file_is_resolved_against_the_config_folder(tmp_path):
    """openscene's (and vlmaps') ``label_names: names.txt`` was read from the working
    folder ('Label-name file not found: names.txt'); a list of names stays a list."""
    folder, params = _adapter_options(tmp_path, "{name: openscene, label_names: names.txt}")
    assert params["label_names"] == str((folder / "names.txt").resolve())
    _, params = _adapter_options(tmp_path, "{name: openscene, label_names: [wall, floor]}")
    assert params["label_names"] == ["wall", "floor"]
