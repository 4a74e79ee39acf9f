"""The console script's signal handlers: Ctrl-C (and SIGTERM) during an import waits for the import to end."""

import subprocess
import sys
import textwrap

import pytest


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_signal_during_an_import_stops_the_run_after_the_import(tmp_path, sig):
    # numba's compiled modules print the traceback of a KeyboardInterrupt raised while they import and turn it into an
    # ImportError, which the command line took for a bug: two lines, exit status 2 (seen once in CI: a Ctrl-C as the
    # workers started).  The handlers now let the import end first
    (tmp_path / "slow_module.py").write_text(f"import signal, time\nsignal.raise_signal(signal.{sig})\ntime.sleep(0.1)\nDONE = True\n")
    script = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {str(tmp_path)!r})
        from patchcloud.stream.cli import install_signal_handlers
        install_signal_handlers()
        try:
            import slow_module
            time.sleep(5)
            print("not stopped")
        except KeyboardInterrupt as exc:
            print("stopped", repr(str(exc)), "after the import:", getattr(sys.modules.get("slow_module"), "DONE", False))
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    expected = "''" if sig == "SIGINT" else "'terminated'"
    assert r.returncode == 0 and r.stdout.strip() == f"stopped {expected} after the import: True", (r.stdout, r.stderr)
