"""Comparing runs in TensorBoard: a real tiny multirun, read back with TensorBoard's own reader
(the event multiplexer and the HParams plugin's session records), as ``tensorboard --logdir``
on the folder above the sweep shows it."""

import math
import os
import re
import subprocess
import sys

import pytest

from gripdem.evaluation.tensorboard_runs import read_runs
from gripdem.runner.config_schema import check_combination
from gripdem.runner.run_names import name_of, swept_keys
from gripdem.runner.tensorboard_log import HP_METRICS, LAYOUT, RUN_SETTINGS


def test_names_say_what_the_sweep_varies():
    overrides = ["split=190-10,100-100", "model=vct", "model.lr=1e-3,3e-3", "seed=range(2)"]
    keys = swept_keys(overrides, {"data.batch_size": "1,2"})
    assert keys == ["split", "model.lr", "seed", "data.batch_size"]
    job = ["split=100-100", "model=vct", "model.lr=3e-3", "seed=1", "data.batch_size=2"]
    assert name_of(job, keys) == "split=100-100,model.lr=0.003,seed=1,data.batch_size=2"
    assert name_of(["model/encoder=graph_conv"], ["model/encoder"]) == "model.encoder=graph_conv"
    assert swept_keys(["model=vct"], None) == []
    paths = swept_keys(["data.path=/a/mine.h5,/b/theirs.h5", "+note=a,b"], None)
    assert name_of(["data.path=/b/theirs.h5", "+note=b"], paths) == "data.path=theirs.h5,note=b"


def _job_config(sweep_dir, num, overrides, sweeper="BasicSweeper", params=None):
    from omegaconf import OmegaConf

    return OmegaConf.create(
        {
            "hydra": {
                "job": {"num": num},
                "overrides": {"task": overrides},
                "sweeper": {"_target_": f"hydra.x.{sweeper}", "params": params},
                "sweep": {"dir": str(sweep_dir)},
                "runtime": {"choices": {"scene": "pbc", "split": "190-10", "model": "vct"}},
            }
        }
    )


def test_a_job_is_named_from_the_sweep_it_belongs_to(tmp_path):
    from omegaconf import OmegaConf

    from gripdem.runner.run_names import job_name

    def sweep_of(*overrides):
        OmegaConf.save(
            {"hydra": {"overrides": {"task": list(overrides)}}}, tmp_path / "multirun.yaml"
        )

    sweep_of("split=190-10,100-100", "model=vct")
    assert job_name(_job_config(tmp_path, 1, ["split=100-100", "model=vct"])) == "split=100-100"
    sweep_of("seed=0,0,1")  # a value given twice: the job number keeps the folders apart
    assert job_name(_job_config(tmp_path, 1, ["seed=0"])) == "seed=0,job=1"
    assert job_name(_job_config(tmp_path, 2, ["seed=1"])) == "seed=1"
    sweep_of("model=vct")  # one job: named by what it runs
    assert job_name(_job_config(tmp_path, 0, ["model=vct"])) == "scene=pbc,split=190-10,model=vct"
    optuna = _job_config(
        tmp_path, 3, ["model.lr=0.00123456", "model.hidden=48"], "OptunaSweeper",
        {"model.lr": "interval(1e-4, 1e-2)", "model.hidden": "choice(16, 32, 48)"},
    )  # fmt: skip
    assert job_name(optuna) == "trial=3,model.lr=0.001235,model.hidden=48"


@pytest.fixture(scope="module")
def sweep(tmp_path_factory, gripdem_data_root, tiny_pbc_path):
    """``-m split.horizon=5,20,20 model=vct experiment=smoke``: two horizons (the tag count
    must not follow the horizon) and one value given twice (distinct runs, never merged).
    Hydra's basic launcher runs the jobs one after the other in the sweep's own process (one
    Lightning import instead of four processes): what is read here, the names, hparams and
    metrics, does not depend on the launcher (gripdem's own is tested in
    test_parallel_launcher.py)."""
    root = tmp_path_factory.mktemp("tb") / "multirun"
    sweep_dir = root / "12-00-00"
    env = {**os.environ, "GRIPDEM_DATA": str(gripdem_data_root)}
    env.pop("GRIPDEM_TRACEBACK", None)
    proc = subprocess.run(
        [
            *(sys.executable, "-m", "gripdem.run", "-m"),
            *("split.horizon=5,20,20", "model=vct", "experiment=smoke", "hydra/launcher=basic"),
            "outputs.figures=false",  # not read here (about half of a smoke job's time)
            f"hydra.sweep.dir={sweep_dir}",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return root, proc.stdout


def test_runs_are_named_by_the_sweep_and_what_differs(sweep):
    root, stdout = sweep
    assert f"compare the runs: tensorboard --logdir {root}" in stdout
    runs = read_runs(root)
    assert sorted(runs) == [
        "12-00-00/split.horizon=20,job=1",
        "12-00-00/split.horizon=20,job=2",
        "12-00-00/split.horizon=5",
    ]
    for name, run in runs.items():  # the HParams row: what differs first, then the sweep
        assert run.trial == f"{name.split('/')[1]} @ 12-00-00"
    for log in (root / "12-00-00").glob("*/run.log"):  # every checkpoint is data, said so
        assert "weights_only` was not set" not in log.read_text(), log
    summary = (root / "12-00-00" / "summary.md").read_text()
    for name in runs:  # the summary's rows are the same folders, in the sweep's order
        assert f"| {name.split('/')[1]} |" in summary
    assert summary.index("split.horizon=5 |") < summary.index("split.horizon=20,job=1 |")


def test_hparams_hold_the_swept_key_and_the_settings_with_their_types(sweep):
    runs = read_runs(sweep[0])
    for run in runs.values():
        hp = run.hparams
        assert not run.has_experiment_tag  # TensorBoard builds the columns from all runs
        assert set(RUN_SETTINGS) - {"trainer.max_steps"} <= set(hp)  # smoke: an epoch budget
        assert hp["split.horizon"] in (5.0, 20.0)  # the swept key, a number
        # what ran, by its own name: split.horizon=20 on the smoke preset's 10-5 is 10-20
        assert hp["split"] == f"10-{int(hp['split.horizon'])}"
        assert hp["model"] == "vct" and hp["experiment"] == "smoke"
        assert hp["model.ar_prior"] is True and hp["in_sample"] is False  # booleans
        assert isinstance(hp["model.lr"], float) and isinstance(hp["scene"], str)


def test_hp_metrics_are_ratios_diameters_and_time(sweep):
    for run in read_runs(sweep[0]).values():
        hp = {tag: points for tag, points in run.scalars.items() if tag.startswith("hp/")}
        assert set(hp) == set(HP_METRICS) - {"hp/test_crps_over_d"}  # deterministic model
        last = {tag: points[-1][1] for tag, points in hp.items()}
        assert 0.1 < last["hp/ratio_cv"] < 3 and 0.1 < last["hp/ratio_ar"] < 3
        assert 1e-5 < last["hp/rmse_over_d"] < 1  # diameters, not metres (1e-9)
        assert 0 <= last["hp/overlap_last_frame"] <= 1
        assert last["hp/seconds_training"] > 0 and last["hp/steps_per_second"] > 0
        assert last["hp/trainable_parameters"] > 1000
        # TensorBoard's metric columns are every scalar tag, sorted; it shows the first five:
        # the error, the two ratios, the overlap and the training time
        assert sorted(run.scalars)[:5] == [
            "hp/overlap_last_frame",
            "hp/ratio_ar",
            "hp/ratio_cv",
            "hp/rmse_over_d",
            "hp/seconds_training",
        ]


def test_scalars_are_few_comparable_and_on_one_axis(sweep):
    runs = list(read_runs(sweep[0]).values())
    tags = [set(run.scalars) for run in runs]
    assert tags[0] == tags[1] == tags[2]  # horizons 5 and 20: the same tags
    scalars = runs[0].scalars
    assert len(scalars) < 60 and "epoch" not in scalars
    assert not [t for t in scalars if re.search(r"/\d+$", t)]  # no card per horizon step
    tag = "test_per_horizon_step/rmse_over_d/model"
    horizon = {run.hparams["split.horizon"]: run.scalars[tag] for run in runs}
    assert [s for s, _ in horizon[5.0]] == list(range(1, 6))  # x: the step of the horizon
    assert [s for s, _ in horizon[20.0]] == list(range(1, 21))
    for run in runs:
        last_step = run.scalars["hp/rmse_over_d"][-1][0]
        assert last_step > 0 and run.scalars["test/rmse_over_d"] == [
            (last_step, pytest.approx(run.scalars["hp/rmse_over_d"][-1][1], rel=1e-6))
        ]  # the test sits at the fit's last step, beside the hp/ values
        assert max(s for s, _ in run.scalars["val/rmse_over_d"]) <= last_step
        for tag, points in run.scalars.items():
            if tag.startswith("test/") or tag.startswith("hp/"):
                assert len(points) == 1 and math.isfinite(points[0][1]), tag


def test_the_custom_scalars_layout_is_written(sweep):
    from tensorboard.backend.event_processing import event_multiplexer

    multiplexer = event_multiplexer.EventMultiplexer()
    multiplexer.AddRunsFromDirectory(str(sweep[0]))
    multiplexer.Reload()
    layouts = multiplexer.PluginRunToTagToContent("custom_scalars")
    assert len(layouts) == 3  # every run carries it (TensorBoard merges them)
    from tensorboard.plugins.custom_scalar import layout_pb2

    run, tags = next(iter(layouts.items()))
    tensor = multiplexer.Tensors(run, next(iter(tags)))[0].tensor_proto
    layout = layout_pb2.Layout.FromString(tensor.string_val[0])
    assert [c.title for c in layout.category] == list(LAYOUT)
    charts = [chart.title for c in layout.category for chart in c.chart]
    assert "RMSE / d per step of the horizon" in charts


def test_an_unknown_logger_option_is_refused_in_one_line():
    from hydra import compose, initialize_config_dir

    from gripdem.run import CONFIG_DIR

    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("config", overrides=["experiment=smoke", "+logger.flsh_secs=5"])
    with pytest.raises(ValueError, match=r"^logger.flsh_secs: not an option .* flush_secs"):
        check_combination(cfg, notes=False)
