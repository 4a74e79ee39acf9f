"""tools/task_stream.py: where a run's wall time goes, from a hand-made task stream."""

import json

import task_stream  # tools/ is on sys.path, see conftest.py


PROFILE = dict(scheduler="processes", slots=2, started=100.0, ready=101.5, ended=108.0, tasks=[
    ["tile: read", 101.5, 103.5, "a"], ["tile: read", 101.6, 103.0, "b"],  # no task from 103.5 to 104.0
    ["fit", 104.0, 107.0, "a"], ["fit", 104.0, 105.0, "b"], ["fit", 105.0, 106.0, "b"],  # then none until 108
])


def test_no_task_spans_are_the_start_the_gaps_between_steps_and_the_end():
    spans = task_stream.no_task_spans(PROFILE)
    assert [(w, round(s, 6)) for w, s in spans] == [("cluster start", 1.5), ("tile: read -> fit", 0.5), ("fit -> end", 1.0)]


def test_each_step_has_its_span_summed_time_ideal_and_longest_task(tmp_path):
    rows = {r[0]: tuple(round(v, 6) if isinstance(v, float) else v for v in r[1:]) for r in task_stream.step_rows(PROFILE)}
    assert rows == {"tile: read": (2, 0.0, 2.0, 2.0, 3.4, 1.7, 2.0), "fit": (3, 2.5, 5.5, 3.0, 5.0, 2.5, 3.0)}
    path = tmp_path / "p.json"
    path.write_text(json.dumps(PROFILE))
    text = task_stream.report(path)
    assert "run 8.00 s (start to workers ready 1.50 s)" in text and text.splitlines()[4].split() == ["no", "task", "in", "all", "3.00"]
