"""--scheduler addresses are checked before anything runs (the schemes dask.distributed takes); --scheduler-file reads one."""

import json

import pytest
from click.testing import CliRunner

from patchcloud.core import PatchcloudIOError, PatchcloudValueError
from patchcloud.stream import RunOptions
from patchcloud.stream.cli import main
from patchcloud.stream.engine.runner import check_scheduler, scheduler_from_file


@pytest.mark.parametrize("address", ["tcp://10.0.0.1:8786", "tls://node7:8786", "ucx://node7", "ws://[::1]:8786", "wss://a.b.c:1",
                                     "node7:8786", "threads", "auto"])
def test_addresses_dask_takes_are_taken(address):
    assert RunOptions(scheduler=address).scheduler == address


@pytest.mark.parametrize("address", ["htps://node7:8786", "node7", "tcp://node7:99999", "tcp://", "", "thread", "tcp://a b:1", 8786])
def test_other_addresses_are_one_error_listing_what_is_taken(address):
    with pytest.raises(PatchcloudValueError, match=r"scheduler must be one of auto, threads, processes, synchronous or a dask "
                                                   r"scheduler address SCHEME://HOST\[:PORT\] with SCHEME one of tcp, tls, ucx, ws, wss"):
        check_scheduler(address)


def test_a_scheduler_file_gives_its_address(tmp_path):
    f = tmp_path / "scheduler.json"
    f.write_text(json.dumps({"type": "Scheduler", "address": "tls://10.1.2.3:8786", "workers": {}}))
    assert scheduler_from_file(f) == "tls://10.1.2.3:8786"
    f.write_text("{}")
    with pytest.raises(PatchcloudIOError, match="scheduler.json: not a dask scheduler file with an address"):
        scheduler_from_file(f)


def test_the_cli_checks_both_before_reading_the_input(tmp_path):
    f = tmp_path / "scheduler.json"
    f.write_text(json.dumps({"address": "smtp://x:25"}))
    for args, said in ([["--scheduler", "htps://x:1"], "scheduler must be one of"],
                       [["--scheduler-file", str(f)], "got 'smtp://x:25'"],
                       [["--scheduler-file", str(f), "--scheduler", "threads"], "not both"]):
        r = CliRunner().invoke(main, ["normals", str(tmp_path / "none.las"), str(tmp_path / "out.las"), *args])
        assert r.exit_code == 2 and r.output.count("\n") == 1 and said in r.output, r.output
