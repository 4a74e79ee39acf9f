"""tools/machine_scaling.py: one table of the speed-up of N threads on compute and on memory."""

import machine_scaling  # tools/ is on sys.path, see conftest.py


def test_the_table_has_a_row_per_kind_of_work_and_a_speed_up_each(tmp_path, capsys):
    out = tmp_path / "t.txt"
    assert machine_scaling.main(["--threads", "2", "--repeats", "1", "--rows", "20000", "--out", str(out)]) == 0
    rows = [line for line in out.read_text().splitlines() if line and not line.startswith("#")]
    assert rows[0].split()[0] == "work" and [r.split("  ")[0].strip() for r in rows[1:]] == ["compute", "memory, streaming",
                                                                                             "memory, random"]
    assert all(r.endswith("x") and float(r.split()[-1].rstrip("x")) > 0 for r in rows[1:])
    assert capsys.readouterr().out.strip() == out.read_text().strip()
