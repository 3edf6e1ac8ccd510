"""Window arithmetic and protocols: counts by formula, temporal order, disjoint simulations."""

import pytest

from gripdem.data.protocols import plan_windows
from gripdem.data.windows import (
    PAPER_SPLITS,
    Segment,
    Split,
    SplitError,
    WindowIndex,
    count_windows,
)


def test_split_parsing():
    assert Split.parse("190-10") == Split(190, 10)
    assert Split.parse({"history": 50, "horizon": 5}).name == "50-5"
    assert [Split.parse(s).history + 1 + Split.parse(s).horizon for s in PAPER_SPLITS] == [201] * 4
    for bad in ("190", "a-b", "0-10", "10-0", {"history": None, "horizon": 3}):
        with pytest.raises(SplitError):
            Split.parse(bad)


def test_window_index_uses_cumulative_counts():
    index = WindowIndex([Segment(0, 0, 2, 3), Segment(4, 5, 1, 0), Segment(7, 1, 3, 2)], 4, 2)
    assert len(index) == 5
    assert [(w.sim, w.start) for w in index] == [(0, 0), (0, 2), (0, 4), (7, 1), (7, 4)]
    w = index[-1]
    assert (w.span, w.last_observed, list(w.target_frames)) == (7, 8, [9, 10])
    with pytest.raises(IndexError):
        index[5]
    assert index.frames_used() == {0: [(0, 11)], 7: [(1, 11)]}
    sparse = WindowIndex([Segment(0, 0, 10, 2)], 2, 1)  # stride longer than a window
    assert sparse.frames_used() == {0: [(0, 4), (10, 14)]}


@pytest.mark.parametrize("split", PAPER_SPLITS + ("20-5",))
@pytest.mark.parametrize("history_len", [None, 7])
@pytest.mark.parametrize("stride", [1, 3])
def test_sims_counts_by_formula_and_disjoint_simulations(split, history_len, stride):
    n_sims, n_frames = 10, 260
    h, f = Split.parse(split).history, Split.parse(split).horizon
    k = h if history_len is None else history_len
    plan = plan_windows(n_sims, n_frames, split, "sims", history_len, train_stride=stride)
    last_start = n_frames - (k + 1 + f)
    assert plan.summary()["sims_train"] == [0, 1, 2, 3, 4, 5]  # fractions 0.6 / 0.2 / 0.2
    assert len(plan.train) == 6 * (last_start // stride + 1)
    assert len(plan.val) == len(plan.test) == 2 * (last_start // f + 1)
    train, val, test = (set(plan.part(p).sims) for p in ("train", "val", "test"))
    assert not (train & val or train & test or val & test)
    assert not plan.in_sample
    assert all(w.stop <= n_frames for p in ("train", "val", "test") for w in plan.part(p))


def test_sims_explicit_lists():
    plan = plan_windows(6, 30, "10-5", "sims", sims={"train": [5, 1], "val": [], "test": [3]})
    assert plan.train.sims == (1, 5) and len(plan.val) == 0 and plan.test.sims == (3,)
    with pytest.raises(SplitError, match="share"):
        plan_windows(6, 30, "10-5", "sims", sims={"train": [1, 2], "test": [2]})
    with pytest.raises(SplitError, match="simulations"):
        plan_windows(2, 30, "10-5", "sims")


@pytest.mark.parametrize("split", PAPER_SPLITS)
@pytest.mark.parametrize("history_len", [None, 30])
def test_time_targets_are_ordered_and_counted(split, history_len):
    n_frames = 620
    s = Split.parse(split)
    k = s.history if history_len is None else history_len
    span = k + 1 + s.horizon
    plan = plan_windows(1, n_frames, split, "time", history_len, train_stride=2)
    b1, b2 = plan.notes["time_boundaries"]
    assert (b1, b2) == (round(0.6 * n_frames), round(0.8 * n_frames))
    assert len(plan.train) == count_windows(0, b1 - span, 2)
    assert len(plan.val) == (b2 - span - (b1 - k - 1)) // s.horizon + 1
    assert len(plan.test) == (n_frames - span - (b2 - k - 1)) // s.horizon + 1
    targets = {p: plan.part(p).target_frames()[0] for p in ("train", "val", "test")}
    assert max(targets["train"]) < min(targets["val"]) <= max(targets["val"]) < min(targets["test"])
    assert not targets["train"] & targets["test"]
    assert min(targets["val"]) == b1 and min(targets["test"]) == b2
    assert max(targets["test"]) <= n_frames - 1


def test_in_sample_protocol_is_in_sample():
    plan = plan_windows(1, 201, "190-10", "in_sample")
    assert plan.in_sample and plan.summary()["in_sample"] is True
    assert list(plan.train) == list(plan.test) == list(plan.val)
    assert len(plan.train) == 1 and plan.train[0].stop == 201
    many = plan_windows(
        2, 40, "10-5", "in_sample", train_stride=4, simulations=[0, 1], in_sample_windows=9
    )
    assert len(many.train) == 9 and many.train.sims == (0, 1)
    with pytest.warns(DeprecationWarning, match="protocol 'paper' was renamed 'in_sample'"):
        old = plan_windows(1, 201, "190-10", "paper")  # the name before gripdem 0.1
    assert old.protocol == "in_sample" and list(old.test) == list(plan.test)


def test_auto_protocol():
    assert plan_windows(3, 30, "10-5").protocol == "sims"
    assert plan_windows(1, 300, "10-5").protocol == "time"


def test_split_that_does_not_fit_says_what_fits():
    with pytest.raises(SplitError) as info:
        plan_windows(1, 300, "100-100", "time")
    msg = str(info.value)
    assert "1 simulation(s) of 300 frames" in msg
    assert "190-10: fits with history_len <= 169" in msg
    assert "100-100: does not fit" in msg
    with pytest.raises(SplitError, match="201 frames.*has 150"):
        plan_windows(4, 150, "190-10", "sims")
    with pytest.raises(SplitError, match="history_len must lie in 1..10"):
        plan_windows(4, 150, "10-5", "sims", history_len=11)
    with pytest.raises(SplitError, match="unknown protocol"):
        plan_windows(4, 150, "10-5", "random")
