"""Sweep summary: jobs laid out as a Hydra multirun writes them, one table in Markdown and CSV."""

import csv
import io
import json
import subprocess
import sys

import pytest

from gripdem.evaluation.sweep_summary import collect, parse_overrides, table, write_summary
from gripdem.summary import main


def make_job(root, number, overrides, metrics=None, config=None):
    job = root / str(number)
    (job / ".hydra").mkdir(parents=True)
    if overrides is not None:
        (job / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    if config is not None:
        (job / ".hydra" / "config.yaml").write_text(config)
    if metrics is not None:
        (job / "metrics.json").write_text(json.dumps(metrics))
    return job


def metrics_of(rmse, cv, time_s):
    return {
        "test/rmse": rmse,
        "test/rmse_over_d": rmse / 2.5e-6,
        "test/rmse_step/001": 0.1 * rmse,
        "test/rmse_constant_velocity_over_d": cv / 2.5e-6,
        "train_seconds": time_s,
        "hparams": {"ignored": 1.0},
    }


@pytest.fixture
def sweep(tmp_path):
    root = tmp_path / "multirun" / "2025-01-31" / "12-00-00"
    (root).mkdir(parents=True)
    (root / "multirun.yaml").write_text("hydra: {}\n")
    make_job(root, 0, ["split=190-10", "model=vct", "scene=lebc"], metrics_of(1e-8, 2e-8, 12.5))
    make_job(root, 1, ["split=100-100", "model=vct", "scene=lebc"], metrics_of(3e-7, 5e-7, 30.0))
    make_job(
        root,
        10,
        ["split=100-100", "model=pct", "+trainer.max_steps=5", "scene=lebc"],
        metrics_of(2e-7, 5e-7, 31.0),
    )
    make_job(root, 2, ["split=190-10", "model=pct", "scene=lebc"], None)  # failed job
    return root


def test_table_has_varying_overrides_and_key_metrics(sweep):
    jobs = collect(sweep)
    assert [j.name for j in jobs] == ["0", "1", "2", "10"]
    header, rows = table(jobs)
    assert header == [
        "job",
        "split",
        "model",
        "trainer.max_steps",
        "status",
        "test/rmse",
        "test/rmse_over_d",
        "test/rmse_constant_velocity_over_d",
        "train_seconds",
    ]
    assert rows[0][:5] == ["0", "190-10", "vct", None, "ok"]
    assert rows[2][4] == "no metrics.json" and rows[2][5:] == [None] * 4
    assert rows[3][3] == "5" and rows[3][5] == 2e-7 and rows[3][-1] == 31.0


def test_written_markdown_and_csv(sweep):
    md, csv_path, text = write_summary(sweep)
    assert md == sweep / "summary.md" and md.read_text() == text
    lines = text.splitlines()
    assert lines[0].startswith("| job | split | model |") and lines[1].startswith("|---|")
    assert "| 1 | 100-100 | vct |  | ok | 3e-07 | 0.12 | 0.2 | 30 |" in lines
    rows = list(csv.reader(io.StringIO(csv_path.read_text())))
    assert rows[0][0] == "job" and len(rows) == 5
    assert float(rows[1][rows[0].index("test/rmse")]) == 1e-8  # full precision in CSV
    # re-running replaces the old summary (it is not a job)
    write_summary(sweep)
    assert len(collect(sweep)) == 4


def test_config_yaml_is_used_without_overrides_and_single_jobs_show_everything(tmp_path):
    make_job(
        tmp_path,
        0,
        None,
        {"test/rmse": 1.0},
        config="model:\n  name: grip\n  hidden: 64\nsplit: 190-10\n",
    )
    make_job(
        tmp_path,
        1,
        None,
        {"test/rmse": 2.0},
        config="model:\n  name: grip\n  hidden: 128\nsplit: 190-10\n",
    )
    header, rows = table(collect(tmp_path))
    assert header == ["job", "model/hidden", "status", "test/rmse"]
    assert [r[1] for r in rows] == [64, 128]
    single = tmp_path / "single"
    make_job(single, 0, ["model=pct", "split=150-50"], {"test/rmse": 1.0})
    assert table(collect(single))[0] == ["job", "model", "split", "status", "test/rmse"]


def test_override_parsing():
    assert parse_overrides(["a=1", "+b.c=x=y", "++d=2", "~e"]) == {
        "a": "1",
        "b.c": "x=y",
        "d": "2",
        "e": "<deleted>",
    }


def test_cli(sweep, tmp_path, capsys):
    assert main([str(sweep), "--metrics", "test/rmse"]) == 0
    out = capsys.readouterr().out
    assert "| job | split | model | trainer.max_steps | status | test/rmse |" in out
    assert main([str(tmp_path / "nope")]) == 2
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main([str(empty)]) == 2
    assert "no Hydra job folders" in capsys.readouterr().err
    done = subprocess.run(
        [sys.executable, "-m", "gripdem.summary", str(sweep)],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "summary.csv" in done.stdout


def test_jobs_that_differ_only_by_seed_are_grouped_with_mean_and_std(tmp_path):
    root = tmp_path / "seeds"
    root.mkdir()
    values = {("grip", 0): 1.0, ("grip", 1): 2.0, ("grip", 2): 4.0, ("pct", 0): 3.0}
    for number, ((model, seed), rmse) in enumerate(values.items()):
        make_job(root, number, [f"model={model}", f"seed={seed}"], metrics_of(rmse, 5.0, 1.0))
    make_job(root, 9, ["model=pct", "seed=1"], None)  # a failed seed is counted as missing
    md, _, markdown = write_summary(root)
    assert "## Mean ± std over seeds" in markdown
    grip = next(line for line in markdown.splitlines() if line.startswith("| grip | 3 |"))
    # mean 7/3, sample std of (1, 2, 4) = 1.528
    assert "2.333 ± 1.5" in grip
    assert any(line.startswith("| pct | 1 | 3 |") for line in markdown.splitlines())
    rows = list(csv.DictReader(io.StringIO((root / "summary_seeds.csv").read_text())))
    assert [r["model"] for r in rows] == ["grip", "pct"]
    assert float(rows[0]["test/rmse_mean"]) == pytest.approx(7 / 3)
    assert float(rows[0]["test/rmse_std"]) == pytest.approx(1.5275252, rel=1e-6)
    assert rows[1]["test/rmse_std"] == "nan" and rows[0]["seeds"] == "3"


def test_no_seed_table_without_seeds(sweep):
    _, _, markdown = write_summary(sweep)
    assert "over seeds" not in markdown and not (sweep / "summary_seeds.csv").exists()


def test_a_sweep_with_a_crashed_job_ends_with_status_1_naming_it(sweep, capsys):
    """A job that crashed before writing its error line (no metrics.json, no error.txt) fails
    the sweep too: its summary row says so and the command ends with status 1."""
    from omegaconf import OmegaConf

    from gripdem.runner.sweep_callback import SweepSummary

    config = OmegaConf.create({"hydra": {"sweep": {"dir": str(sweep)}}})
    with pytest.raises(SystemExit) as ended:
        SweepSummary().on_multirun_end(config)
    assert ended.value.code == 1
    err = capsys.readouterr().err
    assert "1 job(s) of the sweep failed: job 2 (split=190-10 model=pct scene=lebc)" in err
    assert "no metrics.json" in err


def test_jobs_named_by_what_differs_keep_the_sweeps_order(tmp_path):
    root = tmp_path / "sweep"
    for number, name in enumerate(["split=190-10", "split=100-100", "split=150-50"]):
        job = make_job(root, name, [name], metrics_of(1e-8, 2e-8, 1.0))
        (job / ".hydra" / "hydra.yaml").write_text(f"hydra:\n  job:\n    num: {number}\n")
    assert [j.name for j in collect(root)] == ["split=190-10", "split=100-100", "split=150-50"]


def test_the_console_summary_keeps_to_100_columns_with_long_swept_values(tmp_path):
    """Many swept keys with long values: every line keeps to 100 columns (the values are cut),
    the numbers stay whole, and the seeds are grouped with mean ± std."""
    from gripdem.evaluation.sweep_console import console_summary

    root = tmp_path / "sweep"
    long = "data.path=/a/very/long/path/to/somebody/elses/dataset/file_of_many_words_"
    for n, (seed, lr) in enumerate([(0, "1e-3"), (1, "1e-3"), (0, "3e-3"), (1, "3e-3")]):
        metrics = {
            "test/rmse_ratio_constant_velocity": 0.70 + 0.01 * n,
            "test/rmse_ratio_linear_ar": 0.72 + 0.01 * n,
            "test/physics/model/overlap_fraction": 0.0003,
            "run_seconds": 330.0,
        }
        overrides = [f"seed={seed}", f"model.lr={lr}", f"{long}{lr}.h5", "split=190-10"]
        make_job(root, n, overrides, metrics)
    text = console_summary(collect(root))
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 100
    assert lines[0].split()[-4:] == ["AR", "overlap", "%", "min"]
    assert "0.7" in lines[1] and "0.72" in lines[1] and "5.5" in lines[1] and "0.03" in lines[1]
    assert "…" in lines[1]  # the long swept value was cut, not the numbers
    assert "mean ± std over seeds:" in lines
    grouped = lines[lines.index("mean ± std over seeds:") + 1 :]
    assert grouped[0].split()[:2] == ["group", "seeds"] and len(grouped) == 3  # two groups
    assert grouped[1] != grouped[2]  # the paths differ past the cut: still two groups
    assert " 2 " in grouped[1] and "±" in grouped[1]


def test_the_console_shows_swept_values_as_the_run_names_do(tmp_path):
    """A path by its file name, a number to 4 significant figures: the console's rows read as
    the job folders and TensorBoard's runs are named."""
    from gripdem.evaluation.sweep_console import console_summary
    from gripdem.runner.run_names import name_of

    root = tmp_path / "sweep"
    sweeps = [
        ["data.path=/x/y/mine.h5", "model.lr=0.00123456"],
        ["data.path=/x/y/theirs.h5", "model.lr=3e-3"],
    ]
    for n, overrides in enumerate(sweeps):
        make_job(root, n, overrides, metrics_of(1e-8, 2e-8, 1.0))
    rows = console_summary(collect(root)).splitlines()[1:3]
    for row, overrides in zip(rows, sweeps, strict=True):
        name = name_of(overrides, ["data.path", "model.lr"])
        assert row.split()[:2] == name.split(","), (row, name)
    assert rows[0].startswith("data.path=mine.h5 model.lr=0.001235 ")
