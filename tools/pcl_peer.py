"""PCL as a benchmark peer: normals (k-NN or radius) and Difference of Normals from the C++ library, timed.

PCL has no Python binding on PyPI, so the benchmarks build the small
program ``tools/peers/pcl_normals.cpp`` against the Debian package
(``apt-get install libpcl-dev g++ pkg-config``) the first time they need it,
into ``~/.cache/patchcloud/peers`` (outside the repository), and run it on
a cloud written as raw float64.  Its time is the k-d tree build plus the
computation (``NormalEstimationOMP`` with the given thread count, normals
turned to the viewpoint; for DoN ``DifferenceOfNormalsEstimation`` over
both radii); reading and writing the files are not timed.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["SOURCE", "pcl_program", "run_pcl"]

SOURCE = Path(__file__).resolve().parent / "peers" / "pcl_normals.cpp"
_MODULES = ("pcl_features", "pcl_search", "pcl_kdtree", "pcl_common")


def pcl_program() -> tuple[str | None, str]:
    """The path of the compiled PCL peer, building it when needed: (path, "") or (None, why it is missing)."""
    cxx, pkg = shutil.which("g++") or shutil.which("c++"), shutil.which("pkg-config")
    if cxx is None or pkg is None:
        return None, "PCL peer not built: no C++ compiler or pkg-config (apt-get install libpcl-dev g++ pkg-config)"
    flags = subprocess.run([pkg, "--cflags", "--libs", *_MODULES], capture_output=True, text=True)
    if flags.returncode != 0:
        return None, "PCL not installed: pkg-config knows no pcl_features (apt-get install libpcl-dev)"
    version = subprocess.run([pkg, "--modversion", "pcl_common"], capture_output=True, text=True).stdout.strip()
    key = hashlib.sha256(SOURCE.read_bytes() + flags.stdout.encode() + version.encode()).hexdigest()[:12]
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "patchcloud" / "peers"
    exe = cache / f"pcl_normals-{key}"
    if exe.exists():
        return str(exe), ""
    cache.mkdir(parents=True, exist_ok=True)
    tmp = cache / f"{exe.name}.{os.getpid()}.partial"
    r = subprocess.run([cxx, "-O2", "-std=c++17", "-fopenmp", str(SOURCE), "-o", str(tmp), *flags.stdout.split()],
                       capture_output=True, text=True)
    if r.returncode != 0:
        tail = (r.stderr.strip().splitlines() or ["?"])[-1]
        return None, f"PCL peer did not compile (PCL {version}): {tail}"
    tmp.replace(exe)
    return str(exe), ""


def run_pcl(points: np.ndarray, mode: str, args, viewpoint, threads: int) -> tuple[float, np.ndarray]:
    """Run the PCL peer on ``points`` ((N, 3) metres, local frame).

    ``mode`` "knn" (args: k), "radius" (args: r) or "don" (args: r_small,
    r_large).  Returns (seconds, (N, 3) float64 normals or DoN vectors,
    NaN where PCL leaves them undefined).  Raises RuntimeError when the
    peer is missing or fails (the message says why).
    """
    exe, why = pcl_program()
    if exe is None:
        raise RuntimeError(why)
    with tempfile.TemporaryDirectory(prefix="pcl_peer") as d:
        cloud, out = Path(d) / "cloud.f64", Path(d) / "out.f64"
        np.ascontiguousarray(points, dtype=np.float64).tofile(cloud)
        cmd = [exe, str(cloud), str(out), str(int(threads)), mode, *map(str, args), *(f"{v:.6f}" for v in viewpoint)]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise RuntimeError(f"PCL peer failed: {(r.stderr.strip().splitlines() or [r.returncode])[-1]}")
        seconds = float(r.stdout.split()[-1])
        return seconds, np.fromfile(out).reshape(-1, 3)
