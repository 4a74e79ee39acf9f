"""stream.engine.laspy_start and import_hooks: the console script and its workers import laspy without requests."""

import subprocess
import sys
import textwrap

RUN = textwrap.dedent("""
    import sys
    from patchcloud.stream.engine.laspy_start import skip_laspy_http
    first = skip_laspy_http()
    import laspy
    import laspy.copc
    skipped = "requests" not in sys.modules and laspy.copc.requests is None
    again = skip_laspy_http()  # laspy imported: too late, says so
    las = laspy.read(sys.argv[1])
    import importlib.util
    if importlib.util.find_spec("requests") is not None:  # another import of it works as before (where it is installed)
        import requests
        later = requests.__name__
    else:
        later = "requests"
    print(first, skipped, again, len(las.points), later)
""")


def test_laspy_imports_without_requests_and_reads_files(tmp_path):
    from test_stream import write_scene

    src = tmp_path / "scene.las"
    write_scene(src, n=2_000, seed=1)
    out = subprocess.run([sys.executable, "-c", RUN, str(src)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["True", "True", "False", "2000", "requests"]


def test_the_console_script_and_a_worker_process_skip_requests(tmp_path):
    from test_stream import write_scene

    src = tmp_path / "scene.las"
    write_scene(src, n=2_000, seed=1)
    script = textwrap.dedent(f"""
        import sys
        from patchcloud.stream.cli import run
        sys.argv = ["patchcloud", "info", {str(src)!r}]
        try:
            run()
        except SystemExit:
            pass
        import distributed  # what a local worker has imported when dask calls its set-up
        assert "laspy" not in sys.modules or "requests" not in sys.modules
        print("console", "requests" in sys.modules)
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "console False"
    worker = textwrap.dedent("""
        import sys
        import distributed  # noqa: F401  what a worker process has imported before its preload
        from patchcloud.stream.engine import worker_setup

        class Worker:
            state = None

        worker_setup.dask_setup(Worker())
        import laspy  # noqa: F401  what its first task imports
        print("worker", "requests" in sys.modules)
    """)
    out = subprocess.run([sys.executable, "-c", worker], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "worker False"
