"""numba without its BLAS probe, for the processes patchcloud runs itself (the console script, its local workers).

When numba is imported, ``numba.np.arraymath`` checks that a BLAS is
there for ``np.dot`` and ``np.linalg`` in compiled code by importing
``scipy.linalg.cython_blas``, which imports ``scipy.linalg`` and with it
scipy's array-API layer, which makes numpy import ``numpy.testing`` and
``numpy.f2py``: 0.14 s of every run (``python -X importtime``), a fifth of
a small file's whole run.  patchcloud's kernels use neither ``np.dot`` nor
``np.linalg`` (their 3x3 eigen-solver is their own), so
:func:`skip_numba_blas_probe` makes that one import fail while
``numba.np.arraymath`` runs (numba then records "no BLAS" and moves on),
and any other import of ``scipy.linalg`` works as before.  Compiled code
in the same process that used ``np.dot`` would then be refused by numba;
so only the console script (:func:`patchcloud.stream.cli.run`) and the
workers of its local cluster do it, not ``import patchcloud``.

Nor does numba import PyYAML (0.02 s) unless the working directory has
a ``.numba_config.yaml`` for it to read (:func:`skip_numba_yaml`): numba
reads that file with it when it is imported, and for nothing else.

The same processes load numba's cached kernels without the set-up that
only compiling needs (:func:`load_cached_kernels_lightly`).  Before loading
a kernel from its cache, numba "refreshes" its target: it imports every
module that implements Python and numpy for compiled code (``numba.np.*``,
``numba.cpython.*``, ``numba.typed``, ``numba.experimental``) and
registers their typing and lowering rules, 0.07 s of every process (the
first cached kernel's call: 0.105 s, 0.032 s without).  None of that is
used by machine code loaded from a cache; what such code links against is
numba's runtime (initialised here, as numba's refresh does) and the
symbols numba registers when its context is made, with the hash secret of
``numba.cpython.hashing`` (imported here too).  A kernel not in the cache
is compiled as before, and compiling refreshes in full.  Loading a kernel
makes hundreds of calls into LLVM, each under llvmlite's lock, on which
numba hangs a start and an end event ("numba:llvm_lock", for its
compile-time statistics): 4.5 microseconds a call, 0.035 s of a small
file's run.  The same processes take those two callbacks off the lock
(:func:`drop_llvm_lock_events`; the lock itself stays).

A cached kernel holds its machine code (an object file) and the LLVM
bitcode of its module, which numba parses as it loads the kernel (3.4 ms a
kernel, 0.1 s of the 29 a small run loads) for two uses: the names of the
symbols the kernel defines, which numba's JIT engine must know before it
looks one up, and linking the kernel into another one compiled later that
calls it.  The same processes take the names from the object file's symbol
table (the same set: checked for every kernel of a run) and parse the
bitcode only if something links with the kernel
(:func:`defined_symbols`).
"""

from __future__ import annotations

import os
import struct
import sys

from patchcloud.stream.engine.import_hooks import after_importing, hide_while_importing

__all__ = ["skip_numba_blas_probe", "skip_numba_yaml", "load_cached_kernels_lightly", "drop_llvm_lock_events", "PROBED",
           "PROBING", "CONFIGURING", "NUMBA_CONFIG_FILE", "CACHING", "defined_symbols"]

#: The module numba imports to find a BLAS.
PROBED = "scipy.linalg.cython_blas"
#: The numba module that imports it, once, as it is imported.
PROBING = "numba.np.arraymath"
#: The numba module that reads :data:`NUMBA_CONFIG_FILE` with PyYAML, when it is imported.
CONFIGURING = "numba.core.config"
#: numba's own settings file, in the working directory (numba's name for it).
NUMBA_CONFIG_FILE = ".numba_config.yaml"
#: The numba module whose cache loads kernels.
CACHING = "numba.core.caching"


def skip_numba_blas_probe() -> bool:
    """Have ``numba.np.arraymath``, when it is imported, find no BLAS without importing scipy (see the module's notes).

    Returns whether it will: False when numba has already done its probe in this process.
    """
    return hide_while_importing(PROBING, PROBED)


def skip_numba_yaml() -> bool:
    """Have numba, when it is imported, not import PyYAML where the working directory has no :data:`NUMBA_CONFIG_FILE`.

    Returns whether it will: False when numba's configuration is already
    read in this process, or when the file is there (numba reads it as usual).
    """
    if os.path.isfile(NUMBA_CONFIG_FILE):
        return False
    return hide_while_importing(CONFIGURING, "yaml")


def load_cached_kernels_lightly() -> bool:
    """Have numba load cached kernels without refreshing its target first (see the module's notes).

    Takes effect when numba's cache module is imported (at once if it is
    already): numba itself is not imported here, so ``patchcloud --help``
    still starts without it.  Returns False where this numba's cache does
    not work as this expects (numba then loads as it always does).  Loaded
    kernels are the cache's machine code either way: the same results.
    """
    if CACHING in sys.modules:
        return _lighten(sys.modules[CACHING])
    after_importing(CACHING, _lighten)
    return True


def _lighten(caching) -> bool:
    """Replace ``caching.Cache.load_overload`` by one without the target's refresh; False if it is not as expected."""
    cache = getattr(caching, "Cache", None)
    if cache is None or not all(hasattr(cache, n) for n in ("load_overload", "_load_overload", "_guard_against_spurious_io_errors")):
        return False
    if getattr(cache.load_overload, "lightly", False):
        return True
    from numba.core.runtime import nrt

    dropped: list[int] = []

    def load_overload(self, sig, target_context):
        if not dropped:
            dropped.append(drop_llvm_lock_events())  # once, numba being whole by now
        nrt.rtsys.initialize(target_context)  # numba's runtime: what loaded code calls to allocate
        import numba.cpython.hashing  # noqa: F401  its import gives the LLVM symbols of Python's hash secret
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)

    load_overload.lightly = True
    load_overload.__doc__ = cache.load_overload.__doc__
    cache.load_overload = load_overload
    _parse_bitcode_when_linked()
    return True


def _parse_bitcode_when_linked() -> bool:
    """Have numba load a cached kernel's library without parsing its bitcode until it is linked (module notes).

    Returns False, changing nothing, where numba's code library is not as this expects.
    """
    from numba.core import codegen

    library = getattr(codegen, "CPUCodeLibrary", None)
    unserialize = getattr(library, "_unserialize", None)
    for_linking = getattr(library, "_get_module_for_linking", None)
    if unserialize is None or for_linking is None:  # (an engine without its set of names: checked at each load)
        return False
    if getattr(for_linking, "lightly", False):
        return True
    plain = unserialize.__func__

    def _unserialize(cls, codegen_, state):
        name, kind, data = state
        names = defined_symbols(data[0]) if kind == "object" else None
        engine = getattr(codegen_, "_engine", None)
        if names is None or not isinstance(getattr(engine, "_defined_symbols", None), set):
            return plain(cls, codegen_, state)
        self = codegen_.create_library(name)
        self.enable_object_caching()
        self._set_compiled_object(data[0])
        self._bitcode_for_linking = data[1]
        self._finalize_final_module()
        engine._defined_symbols |= names  # what numba's engine._load_defined_symbols(parsed bitcode) would add
        return self

    def _get_module_for_linking(self):
        bitcode = self.__dict__.pop("_bitcode_for_linking", None)
        if bitcode is not None and self._shared_module is None:
            self._shared_module = codegen.ll.parse_bitcode(bitcode)
        return for_linking(self)

    _get_module_for_linking.lightly = True
    library._unserialize = classmethod(_unserialize)
    library._get_module_for_linking = _get_module_for_linking
    return True


def defined_symbols(code: bytes) -> set[str] | None:
    """The names of the symbols an ELF64 little-endian object file defines (functions and data), or None for another
    format (numba then parses the kernel's bitcode as usual).

    >>> defined_symbols(b"MZ not an ELF file") is None
    True
    """
    if len(code) < 64 or code[:4] != b"\x7fELF" or code[4] != 2 or code[5] != 1:
        return None
    shoff = struct.unpack_from("<Q", code, 0x28)[0]
    entsize, count = struct.unpack_from("<HH", code, 0x3A)
    sections = [struct.unpack_from("<IIQQQQIIQQ", code, shoff + i * entsize) for i in range(count)]
    names = set()
    for _, kind, _, _, offset, size, link, _, _, each in sections:
        if kind != 2 or each == 0:  # SHT_SYMTAB
            continue
        strings = sections[link][4]
        for k in range(size // each):
            at, info, _, section = struct.unpack_from("<IBBH", code, offset + k * each)
            if section == 0 or at == 0 or info & 0xF in (3, 4):  # undefined, unnamed, STT_SECTION, STT_FILE
                continue
            names.add(code[strings + at:code.index(b"\0", strings + at)].decode())
    return names


def drop_llvm_lock_events() -> int:
    """Take numba's "numba:llvm_lock" event callbacks off llvmlite's lock (see the module's notes); how many were taken.

    Called once by the kernel loader of :func:`load_cached_kernels_lightly`, before its first load.
    Other callbacks on the lock are left; where llvmlite keeps them
    otherwise than this expects, nothing is taken (0).
    """
    from numba.core import base  # registers the callbacks as it is imported; its llvmlite binding is the one numba uses

    ffi = getattr(getattr(base, "ll", None), "ffi", None)
    lock = getattr(getattr(ffi, "lib", None), "_lock", None)
    pairs = getattr(lock, "_cblist", None)
    if not isinstance(pairs, list) or not hasattr(ffi, "unregister_lock_callback"):
        return 0
    numba_events = [p for p in pairs if all("_initialize_llvm_lock_event" in getattr(f, "__qualname__", "") for f in p)]
    for acquire, release in numba_events:
        ffi.unregister_lock_callback(acquire, release)
    return len(numba_events)
