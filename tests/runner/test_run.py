"""The experiment runner: composition of every config option, and smoke runs end to end."""

import json
import math
from pathlib import Path

import h5py
import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException

from gripdem.evaluation.tensorboard_runs import read_runs
from gripdem.inference.model_file import read_model_file
from gripdem.run import CONFIG_DIR
from gripdem.runner.experiment import run_experiment
from gripdem.runner.tensorboard_log import HP_METRICS

ROOT = Path(__file__).resolve().parents[2]

GROUPS = {
    "scene": ["pbc", "lebc"],
    "preset": ["tiny", "default", "paper"],
    "split": ["190-10", "180-20", "150-50", "100-100", "10-5", "custom"],
    "model": [
        "contact",
        "ensemble",
        "grip",
        "pct",
        "vct",
        "grip_paper",
        "pct_paper",
        "vct_paper",
        "vct_paper_exact",
    ],
    "trainer": ["cpu", "gpu", "ddp"],
    "experiment": ["smoke", "default", "paper"],
    "hparams_search": ["optuna"],
    "hydra/launcher": ["local_parallel", "slurm"],
    "hydra/sweeper/pruner": ["successive_halving", "median", "none"],
}


#: config options that need an optional Hydra plugin (extras `sweep` and `cluster`)
PLUGINS = {
    "hparams_search=optuna": "optuna",
    "hydra/launcher=slurm": "hydra_plugins.hydra_submitit_launcher",
}


def compose_run(overrides: list[str], hydra_node: bool = True):
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        return compose("config", overrides=overrides, return_hydra_config=hydra_node)


@pytest.mark.parametrize(
    "override", [f"{group}={option}" for group, options in GROUPS.items() for option in options]
)
def test_every_config_option_composes(override):
    plugin = PLUGINS.get(override)
    if plugin:  # launchers and sweepers come with the optional extras (sweep, cluster)
        pytest.importorskip(plugin)
    extra = ["split.history=20", "split.horizon=3"] if override == "split=custom" else []
    if override.startswith("hydra/sweeper/pruner="):  # the study sweeper's pruners
        pytest.importorskip("optuna")
        extra = ["hparams_search=optuna"]
    cfg = compose_run([*extra, override])
    assert cfg.split.history > 0 and cfg.split.horizon > 0
    assert cfg.data.encoding == cfg.model.encoding


def test_every_config_file_is_listed_here():
    conf = Path(CONFIG_DIR)
    for group, options in GROUPS.items():
        on_disk = sorted(p.stem for p in (conf / group).glob("*.yaml"))
        assert on_disk == sorted(options), group


def test_custom_split_and_defaults():
    cfg = compose_run(["split=custom", "split.history=50", "split.horizon=5"])
    assert cfg.split.name == "50-5"
    default = compose_run([])
    assert (default.scene.name, default.split.name, default.model.name) == (
        "pbc",
        "190-10",
        "contact",
    )
    assert default.data.history_len == 10  # experiment=default is the default preset
    # a step budget: one simulation of the user's gets as many updates as the default six
    # (the model's own: the lean contact encoder takes twice the steps of the paper models)
    assert (default.trainer.max_steps, default.trainer.max_epochs) == (2400, -1)
    # grip, pct and vct share the default model's form and budget (only the mode differs)
    assert compose_run(["model=vct"]).trainer.max_steps == 2400
    assert compose_run(["model=vct_paper"]).trainer.max_steps == 1820
    assert compose_run(["trainer.max_steps=50"]).trainer.max_steps == 50
    # the data's graph cut-off follows the encoder (one source of truth)
    assert default.data.graph_cutoff == default.model.encoder.cutoff == 1.15
    assert compose_run(["model=grip_paper"]).data.graph_cutoff == 3.0
    assert compose_run(["model=vct"]).data.encoding.value == "unwrapped"


def test_the_command_line_wins_over_a_preset_or_the_pair_is_refused_naming_both():
    """A preset chooses sizes; a split, preset or value given on the command line is what
    runs (experiment=smoke once replaced split=190-10 by 10-5 without a word)."""
    from gripdem.runner.config_schema import check_combination

    smoke = compose_run(["experiment=smoke"])
    assert (smoke.split.name, smoke.preset.name) == ("10-5", "tiny")
    assert compose_run(["experiment=smoke", "split.horizon=20"]).split.name == "10-20"
    assert compose_run(["experiment=smoke", "model.hidden=64"]).model.hidden == 64
    assert compose_run(["experiment=default", "data.history_len=20"]).data.history_len == 20
    assert compose_run(["experiment=smoke", "preset=default"]).preset.name == "default"
    too_long = compose_run(["experiment=smoke", "split=190-10"])
    assert too_long.split.name == "190-10"  # the command line's split, not the preset's
    with pytest.raises(ValueError) as refused:
        check_combination(too_long, notes=False)
    line = str(refused.value)
    assert "split=190-10" in line and "preset=tiny" in line and "experiment=smoke" in line
    check_combination(compose_run(["experiment=smoke", "split=190-10", "preset=default"]))


def test_no_preset_sets_the_scene_the_split_or_the_data_size():
    """What names a run (scene, split, dataset size) comes from its group files, which the
    command line replaces; a preset may only choose them as defaults."""
    import yaml

    for path in (Path(CONFIG_DIR) / "experiment").glob("*.yaml"):
        keys = set(yaml.safe_load(path.read_text()) or {})
        assert not keys & {"scene", "split", "preset"}, path.name


def test_the_contact_encoder_refuses_the_paper_frame():
    cfg = compose_run(["model=contact", "model.encoding=sincos"], hydra_node=False)
    from gripdem.runner.config_schema import check_combination

    with pytest.raises(ValueError, match="exact frame"):
        check_combination(cfg)


def test_the_ar_prior_refuses_the_paper_frame():
    from gripdem.runner.config_schema import check_combination

    cfg = compose_run(["model=grip_paper", "model.ar_prior=true"], hydra_node=False)
    with pytest.raises(ValueError, match="ar_prior"):
        check_combination(cfg)
    assert compose_run(["model=contact"]).model.ar_prior
    assert not compose_run(["model=grip_paper"]).model.ar_prior


def test_the_linear_ar_lags_fit_the_history_the_windows_hold():
    """``baselines.ar_lags`` beyond the history is refused by the config check, so a sweep
    names such a job before any job runs (it once failed each job after its data and
    Lightning were loaded, 11 s in)."""
    from gripdem.runner.config_schema import check_combination

    check_combination(compose_run(["experiment=smoke", "baselines.ar_lags=5"], hydra_node=False))
    for extra, lags, history in (([], 6, 5), ([], 0, 5), (["data.history_len=3"], 4, 3)):
        cfg = compose_run(["experiment=smoke", *extra, f"baselines.ar_lags={lags}"], False)
        refused = rf"^baselines.ar_lags={lags} must lie in 1\.\.{history}, the history"
        with pytest.raises(ValueError, match=refused):
            check_combination(cfg, notes=False)


def test_the_ensemble_model_is_the_default_model_with_noise_and_its_own_score():
    """model=ensemble: the default model's form, latent noise, the fair CRPS over 2 members,
    and its best checkpoint on the validation CRPS (every other model: the RMSE)."""
    ensemble, default = compose_run(["model=ensemble"]), compose_run([])
    assert ensemble.model.encoder.noise_channels == 16 and default.model.encoder.noise_channels == 0
    assert (ensemble.model.loss, ensemble.model.members) == ("crps", 2)
    assert ensemble.callbacks.checkpoint.monitor == "val/crps"
    assert default.callbacks.checkpoint.monitor == "val/rmse"
    for key in ("decoder", "zero_mean", "ar_prior", "horizon"):
        assert ensemble.model[key] == default.model[key]


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("model.decoder_mode=gripp", "gripp"),
        ("split.horizon=ten", "ten"),
        ("data.protocl=sims", "protocl"),
        ("model.encoder.trainable_graph=full", "full"),
        ("data.history_len=1.5", "1.5"),
        ("logger.nmae=x", "nmae"),  # an unknown logger option
    ],
)
def test_typos_and_wrong_types_fail_at_composition(override, message):
    with pytest.raises(ConfigCompositionException) as info:
        compose_run([override])
    assert message in str(info.value) + str(info.value.__cause__)


def run_smoke(tmp_path, monkeypatch, data_root, overrides):
    monkeypatch.setenv("GRIPDEM_DATA", str(data_root))
    out = tmp_path / "run"
    overrides = ["experiment=smoke", f"logger.save_dir={out}", *overrides]
    cfg = compose_run(overrides, hydra_node=False)
    report = run_experiment(cfg, out)
    return cfg, out, report


def run_in_events(out: Path):
    """The run as TensorBoard reads it: its folder is the run (one run, named '.')."""
    runs = read_runs(out)
    assert list(runs) == ["."], runs.keys()
    return runs["."]


def _model_scene_pairs():
    """Every model end to end in one scene at least, the default model in both, each scene
    under every decoder family; the other pairs run in the slow tier (each decoder mode's
    decoding in both scenes is guarded in the default tier by tests/models/test_module.py's
    shapes test, on the same tiny scenes)."""
    default_tier = {
        ("contact", "pbc"), ("contact", "lebc"), ("grip", "pbc"), ("pct", "lebc"),
        ("vct", "lebc"), ("vct_paper", "pbc"),
    }  # fmt: skip
    return [
        pytest.param(scene, model, marks=() if (model, scene) in default_tier else pytest.mark.slow)
        for model in ("contact", "grip", "pct", "vct", "vct_paper")
        for scene in ("pbc", "lebc")
    ]


@pytest.mark.parametrize(("scene", "model"), _model_scene_pairs())
def test_smoke_run_end_to_end(tmp_path, monkeypatch, gripdem_data_root, request, scene, model):
    request.getfixturevalue(f"tiny_{scene}_path")  # generated once per session
    # the figures (half of a smoke run's time) are read in one pair per scene; they plot the
    # predictions, whatever model made them
    figures_read = (model, scene) in {("grip", "pbc"), ("vct", "lebc")}
    cfg, out, report = run_smoke(
        tmp_path,
        monkeypatch,
        gripdem_data_root,
        [f"scene={scene}", f"model={model}", f"outputs.figures={figures_read}"],
    )
    metrics = json.loads((out / "metrics.json").read_text())
    for key in (
        "test/rmse",
        "test/rmse_constant_velocity",
        "test/rmse_linear_ar",
        "test/rmse_ratio_constant_velocity",
        "val/rmse_best",
        *(k for k in HP_METRICS if k != "hp/test_crps_over_d"),  # an ensemble's
    ):
        assert math.isfinite(metrics[key]), key
    run = run_in_events(out)
    scalars = set(run.scalars)
    assert run.hparams["model"] == model and run.hparams["scene"] == scene
    assert set(HP_METRICS) - {"hp/test_crps_over_d"} <= scalars
    assert {
        "train/loss",
        "val/rmse_over_d",
        "test/rmse_over_d",
        "test/rmse_ratio_linear_ar",
    } <= scalars
    figures = ("rmse_per_step", "crossers", "velocity_profile", "parity_z", "pair_distances")
    for name in (*figures, "physics") if figures_read else ():
        assert (out / "figures" / f"{name}.png").stat().st_size > 5000
    assert figures_read == (out / "figures").exists()
    assert (out / "checkpoints" / "best.ckpt").exists()
    assert (out / "checkpoints" / "best.safetensors").exists()  # the shareable model file
    card = read_model_file(out / "checkpoints" / "best.safetensors", tensors=False)[2]
    split = card["training_data"]["split"]  # the in-sample check away from this folder reads it
    assert split == {k: metrics["data"][k] for k in split} and split["sims_train"]
    assert (out / "trajectories" / "window000_pred.xyz").exists()
    with h5py.File(out / "predictions.h5") as h5:
        pred = h5["pred_positions"][()]
        box = h5.attrs["box"]
        assert h5.attrs["boundary"] == ("periodic" if scene == "pbc" else "lees_edwards")
        assert pred.shape == h5["true_positions"].shape
    assert np.all(pred >= -box / 2) and np.all(pred < box / 2)
    assert report["in_sample"] is False
    assert 0.0 <= metrics["test/physics/model/overlap_fraction"] <= 1.0
    for name in ("truth", "model", "constant_velocity", "linear_ar", "mean_flow", "stay"):
        assert math.isfinite(metrics[f"test/physics/{name}/non_affine_rms_over_d"]), name
    assert ("test/crossers/n" in metrics) == (scene == "lebc")
    assert {"test/physics/gr_distance", "test/physics/coordination_contact_over_truth"} <= scalars


def test_a_short_horizon_model_is_tested_chained_over_the_split(
    tmp_path, monkeypatch, gripdem_data_root, tiny_lebc_path
):
    """``model.horizon`` shorter than the split's: trained on its own horizon, tested on the
    split's windows through the in-memory stepper (contact correction on), every baseline
    beside it on the same windows."""
    cfg, out, report = run_smoke(
        tmp_path,
        monkeypatch,
        gripdem_data_root,
        ["scene=lebc", "model.horizon=2", "outputs.figures=false"],
    )
    metrics = json.loads((out / "metrics.json").read_text())
    f = int(cfg.split.horizon)
    assert f > 2 and report["test_chained"]["model_horizon"] == 2
    assert report["test_chained"]["contact_correction"] is True
    assert all(math.isfinite(metrics[f"test/rmse_step/{j:03d}"]) for j in range(1, f + 1))
    with h5py.File(out / "predictions.h5") as h5:
        assert h5["pred_positions"].shape[1] == f
    assert math.isfinite(metrics["test/rmse_ratio_constant_velocity"])


#: every option name removed in gripdem 0.2.0: the command lines that use it (set, added,
#: among a sweep's choices), and the same command under the new name
REMOVED = {
    "experiment=fast": (
        [["experiment=fast"], ["-m", "experiment=smoke,fast"]],
        ["experiment=default"],
    ),
    "model.fast_steps": (
        [["model.fast_steps=100"], ["+model.fast_steps=100"], ["~model.fast_steps"]],
        ["model.train_steps=100"],
    ),
    "model=interaction": (
        [["model=interaction"], ["-m", "model=contact,interaction"]],
        ["model=contact"],
    ),
    "model/encoder=interaction": (
        [["model=grip", "model/encoder=interaction"]],
        ["model=grip", "model/encoder=contact"],
    ),
    "model.encoder.name=interaction": (
        [["model.encoder.name=interaction"], ["model.encoder.name='interaction'"]],
        ["model.encoder.name=contact"],
    ),
    "data.protocol=paper": (
        [["data.protocol=paper"], ["--cfg", "job", "data.protocol=paper"]],
        ["data.protocol=in_sample"],
    ),
    "data.paper_windows": (
        [["data.paper_windows=3"], ["+data.paper_windows=3"]],
        ["data.in_sample_windows=3"],
    ),
}


@pytest.mark.parametrize("old_name", REMOVED)
def test_removed_names_are_refused_in_one_line_naming_the_new_one(old_name):
    """Each name renamed in 0.1.0 is refused in 0.2.0 by gripdem's own line (not Hydra's
    message for a missing config file or key), however it is given; its new name composes;
    every removed name is still listed on the configuration page."""
    from gripdem.runner.renamed_options import RENAMED, refuse_removed_names

    line = (
        f"{old_name} was renamed {RENAMED[old_name][0]} in gripdem 0.1.0 and removed in 0.2.0: "
        f"use {RENAMED[old_name][0]}"
    )
    old_lines, new_overrides = REMOVED[old_name]
    for argv in old_lines:
        with pytest.raises(ValueError) as refused:
            refuse_removed_names(argv)
        assert str(refused.value) == line, argv
    refuse_removed_names(new_overrides)  # the new name passes
    compose_run(new_overrides)  # and composes
    with pytest.raises(ConfigCompositionException):  # the old one is gone from the config
        compose_run(old_lines[0])
    page = (ROOT / "docs" / "reference" / "configuration.md").read_text()
    assert f"| `{old_name}` | `{RENAMED[old_name][0]}` |" in page


def test_every_removed_name_is_tested():
    from gripdem.runner.renamed_options import RENAMED

    assert set(RENAMED) == set(REMOVED)
    assert all(
        renamed == "0.1.0" and removed == "0.2.0" for _, renamed, removed in RENAMED.values()
    )
