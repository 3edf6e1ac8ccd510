"""The claims verdicts on synthetic sweeps whose answers are known by construction."""

import json
import math

import pytest

from gripdem.claims import main
from gripdem.evaluation.claims import HELD, NOT_HELD, UNDECIDED, combine, decide, evaluate
from gripdem.evaluation.sweep_summary import runs_by_group

SPLITS = ("190-10", "180-20", "150-50", "100-100")


def write_job(root, number, scene, split, model, seed, rmse, crossers=None, overlap=0.01):
    job = root / str(number)
    (job / ".hydra").mkdir(parents=True)
    overrides = [f"scene={scene}", f"split={split}", f"model={model}", f"seed={seed}"]
    (job / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    metrics = {
        "test/rmse": rmse,
        "test/physics/model/overlap_fraction": overlap,
        "test/physics/truth/overlap_fraction": 0.0,
        "hparams": {"scene": scene, "split": split, "model": model, "seed": seed},
    }
    if crossers is not None:
        metrics["test/rmse_crossers"] = crossers
    (job / "metrics.json").write_text(json.dumps(metrics))


@pytest.fixture
def sweep(tmp_path):
    """pbc: PCT 10 % below GRIP at 190-10, 40 % below at 100-100 (noise 0.5 %): held, gap
    grows. lebc: VCT worse than GRIP at 190-10 beyond the noise: the LE claim fails. Overlap:
    every model overlaps except grip at lebc 100-100 (0): the overlap claim fails there."""
    root = tmp_path / "sweep"
    jitter = (-0.005, 0.0, 0.005)
    number = 0
    for scene in ("pbc", "lebc"):
        for split in SPLITS:
            long = split in ("150-50", "100-100")
            base = {"grip": 1.0, "pct": 0.9 if split != "100-100" else 0.6, "vct": 0.95}
            if scene == "lebc":
                base = {"grip": 1.0, "pct": 0.9, "vct": 1.2 if split == "190-10" else 0.85}
                if long:
                    base["pct"] = 0.8
            for model, value in base.items():
                for seed, eps in enumerate(jitter):
                    overlap = 0.0 if (scene, split, model) == ("lebc", "100-100", "grip") else 0.02
                    crossers = value + eps if scene == "lebc" else None
                    write_job(
                        root, number, scene, split, model, seed, value + eps, crossers, overlap
                    )
                    number += 1
    return root


def test_claim_verdicts_match_the_construction(sweep):
    claims = dict(evaluate(runs_by_group([sweep])))
    pbc, lebc, overlap = claims.values()
    assert combine(pbc) == HELD
    assert all(p.verdict == HELD for p in pbc)
    assert any("gap grows" in p.statement for p in pbc)
    assert combine(lebc) == NOT_HELD
    failed = [p.statement for p in lebc if p.verdict == NOT_HELD]
    assert "lebc 190-10: vct beats grip (test RMSE)" in failed
    assert "lebc 190-10: vct beats pct (test RMSE)" in failed
    assert "lebc 100-100: pct beats vct (test RMSE)" in [
        p.statement for p in lebc if p.verdict == HELD
    ]
    assert combine(overlap) == NOT_HELD
    assert [p.statement for p in overlap if p.verdict == NOT_HELD] == [
        "lebc 100-100 grip: some overlap"
    ]


def test_decide_needs_two_seeds_and_the_margin():
    assert decide(1.0, 0.01, 3) == (HELD, pytest.approx(10.0))
    assert decide(-1.0, 0.01, 3)[0] == NOT_HELD
    assert decide(0.1, 0.01, 3) == (UNDECIDED, pytest.approx(1.0))
    assert decide(1.0, 0.01, 1)[0] == UNDECIDED
    assert math.isnan(decide(1.0, math.nan, 3)[1])


def test_cli_writes_claims_md(sweep, capsys, tmp_path):
    assert main([str(sweep), "--out", str(tmp_path)]) == 0
    text = (tmp_path / "claims.md").read_text()
    assert (
        "## PBC: PCT beats GRIP++ at every split; the gap grows with the horizon: **held**" in text
    )
    assert "**not held**" in text
    assert main([str(tmp_path / "missing")]) == 2
    assert "no such sweep folder" in capsys.readouterr().err
