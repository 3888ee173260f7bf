"""A fit's progress is one plain record (``fitting.run_state.RunState``): what a checkpoint saves of it comes
back the same, and a saved state that does not fit the fit resuming it is refused in one line."""

import json

import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.run_state import FitShape, RunState

SHAPE = FitShape(n=3, manip_names=("time_offset_s",), ladder=None, intervals_planned=True, n_takes=1)


def _running():
    s = RunState(stage_quality=None, stage_end=90)
    s.track(None, 12.5, [0.1, 0.2, 0.3])
    s.track(None, 13.0, [0.4, 0.5, 0.6])  # worse: not kept
    record = {"stage": "search", "quality": None, "evaluations": 40, "generations": 5, "best_f": 12.5}
    s.end_stage(dict(record, stop="budget"), [[8, 20.0], [40, 12.5]], 40)
    s.stage, s.start_f, s.elapsed, s.exploded, s.cut_batches = "profile", 14.0, 3.5, 2, 1
    s.profile = {"time_offset_s": {"separated": True, "uncertainty": 0.002}}
    return s


def _saved(s):
    """The state as a checkpoint holds it: through JSON text."""
    return json.loads(json.dumps(s.saved_stages(None, None))), json.loads(json.dumps(s.saved_outcome()))


def test_a_saved_state_reads_back_the_same():
    s = _running()
    assert s.best_by_quality == {None: [12.5, [0.1, 0.2, 0.3]]}
    assert s.records[0]["stop"] == "budget" and s.search_stop == "budget" and s.done_evals == 40
    assert s.history_prev == [[8, 20.0], [40, 12.5]]
    stages, outcome = _saved(s)
    back, ladder = RunState.from_saved(stages, outcome, SHAPE, "ck.json")
    assert ladder is None
    for name in ("stage", "stage_end", "done_evals", "records", "best_by_quality", "history_prev", "search_stop"):
        assert getattr(back, name) == getattr(s, name), name
    for name in ("profile", "start_f", "elapsed", "exploded", "cut_batches"):
        assert getattr(back, name) == getattr(s, name), name
    assert not back.finished and back.stop_reason is None  # resumed: running until it stops again


def test_reopening_the_search_forgets_the_stages_after_it():
    s = _running()
    s.reopen_search(200)
    assert (s.stage, s.stage_end, s.records, s.profile, s.history_prev) == ("search", 200, [], None, [])
    assert s.done_evals == 1  # the start point, scored before the search, stays counted


@pytest.mark.parametrize(
    "spoil, what",
    [
        (lambda st: st.pop("records"), "fields"),
        (lambda st: st.update(stage="elsewhere"), "stage"),
        (lambda st: st["best_by_quality"][0][2].pop(), "best_by_quality"),
        (lambda st: st.update(profile={"handle_0": {"separated": True}}), "profile"),
        (lambda st: st.update(cut_batches=-1), "cut_batches"),
        (lambda st: st.update(again={**AGAIN, "ends": [[1.5, [0.1, "y"]]]}), "again"),
        (lambda st: st.update(again={**AGAIN, "ends": [[float("nan"), [0.1]]]}), "again"),
        (lambda st: st.update(intervals=dict(INTERVALS, rise=[[0.1, 0.2, "x"], None, None])), "intervals"),
        (lambda st: st.update(intervals=dict(INTERVALS, rise=[[0.1, 0.2, 0.3]])), "intervals"),
    ],
)
def test_a_saved_state_that_does_not_fit_the_fit_is_refused_in_one_line(spoil, what):
    stages, outcome = _saved(_running())
    spoil(stages)
    with pytest.raises(ClothFitError) as e:
        RunState.from_saved(stages, outcome, SHAPE, "ck.json")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("checkpoint ck.json: bad 'stages'") and what in msg


AGAIN = {"searches": 1, "start": 40, "why": ["above"], "ended": None}
# an intervals stage in its sampling phase (three coordinates), as ``intervals.start`` and its axes leave it
INTERVALS = {"phase": "sample", "u0": [0.5] * 3, "h": [0.03] * 3, "U": [], "F": [], "round": 0, "props": []}


def test_the_intervals_stage_and_its_axes_rises_read_back_and_an_older_state_without_them_too():
    s = _running()
    s.intervals = dict(INTERVALS, rise=[[0.03, 0.5, None], None, [0.09, 0.0, 1.2]])
    stages, outcome = _saved(s)
    assert RunState.from_saved(stages, outcome, SHAPE, "ck.json")[0].intervals == s.intervals
    stages["intervals"] = dict(INTERVALS)  # saved before the rises were kept
    assert RunState.from_saved(stages, outcome, SHAPE, "ck.json")[0].intervals == INTERVALS


def test_the_searches_again_and_where_each_ended_read_back_and_an_older_state_without_them_too():
    s = _running()
    s.again = dict(AGAIN, ends=[[1.5, [0.25, 0.5]], []])
    stages, outcome = _saved(s)
    assert RunState.from_saved(stages, outcome, SHAPE, "ck.json")[0].again == s.again
    stages["again"] = dict(AGAIN)  # saved before the searches' ends were kept
    assert RunState.from_saved(stages, outcome, SHAPE, "ck.json")[0].again == dict(AGAIN, ends=[])


def test_a_state_saved_before_cut_batches_were_recorded_still_reads():
    stages, outcome = _saved(_running())
    del stages["cut_batches"]
    back, _ = RunState.from_saved(stages, outcome, SHAPE, "ck.json")
    assert back.cut_batches == 0
