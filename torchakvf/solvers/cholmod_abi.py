"""CHOLMOD 3.0 (SuiteSparse 5.x) as ctypes sees it: the leading fields of its structs, the
functions called, and the check that the library inside cholespy's extension module is the one
this layout was written for (:func:`library`; see :mod:`.cholmod` for why and how it is used).
"""
from __future__ import annotations

import contextlib
import ctypes as C
import glob
import os
import threading

#: CHOLMOD constants (cholmod_core.h / cholmod_cholesky.h, CHOLMOD 3.0).
_SIMPLICIAL = 0
_AUTO = 1
_NATURAL, _GIVEN, _AMD, _METIS, _NESDIS = 0, 1, 2, 3, 4
_INT, _REAL, _DOUBLE, _PATTERN = 0, 1, 0, 0
_SYS_A = 0
_MAXMETHODS = 9


class _Method(C.Structure):
    _fields_ = [("lnz", C.c_double), ("fl", C.c_double), ("prune_dense", C.c_double),
                ("prune_dense2", C.c_double), ("nd_oksep", C.c_double), ("other_1", C.c_double * 4),
                ("nd_small", C.c_size_t), ("other_2", C.c_size_t * 4), ("aggressive", C.c_int),
                ("order_for_lu", C.c_int), ("nd_compress", C.c_int), ("nd_camd", C.c_int),
                ("nd_components", C.c_int), ("ordering", C.c_int), ("other_3", C.c_size_t * 4)]


class _Common(C.Structure):
    # The leading fields of cholmod_common; the rest (workspace pointers, statistics) is
    # CHOLMOD's own and only needs room: the tail is far larger than the real struct's.
    _fields_ = [("dbound", C.c_double), ("grow0", C.c_double), ("grow1", C.c_double),
                ("grow2", C.c_size_t), ("maxrank", C.c_size_t), ("supernodal_switch", C.c_double),
                ("supernodal", C.c_int), ("final_asis", C.c_int), ("final_super", C.c_int),
                ("final_ll", C.c_int), ("final_pack", C.c_int), ("final_monotonic", C.c_int),
                ("final_resymbol", C.c_int), ("zrelax", C.c_double * 3), ("nrelax", C.c_size_t * 3),
                ("prefer_zomplex", C.c_int), ("prefer_upper", C.c_int),
                ("quick_return_if_not_posdef", C.c_int), ("prefer_binary", C.c_int),
                ("print", C.c_int), ("precise", C.c_int), ("try_catch", C.c_int),
                ("error_handler", C.c_void_p), ("nmethods", C.c_int), ("current", C.c_int),
                ("selected", C.c_int), ("method", _Method * (_MAXMETHODS + 1)),
                ("postorder", C.c_int), ("default_nesdis", C.c_int), ("_rest", C.c_char * 32768)]


class _Sparse(C.Structure):
    _fields_ = [("nrow", C.c_size_t), ("ncol", C.c_size_t), ("nzmax", C.c_size_t), ("p", C.c_void_p),
                ("i", C.c_void_p), ("nz", C.c_void_p), ("x", C.c_void_p), ("z", C.c_void_p),
                ("stype", C.c_int), ("itype", C.c_int), ("xtype", C.c_int), ("dtype", C.c_int),
                ("sorted", C.c_int), ("packed", C.c_int)]


class _Dense(C.Structure):
    _fields_ = [("nrow", C.c_size_t), ("ncol", C.c_size_t), ("nzmax", C.c_size_t), ("d", C.c_size_t),
                ("x", C.c_void_p), ("z", C.c_void_p), ("xtype", C.c_int), ("dtype", C.c_int)]


class _Factor(C.Structure):
    _fields_ = [("n", C.c_size_t), ("minor", C.c_size_t), ("Perm", C.c_void_p), ("ColCount", C.c_void_p),
                ("IPerm", C.c_void_p), ("nzmax", C.c_size_t), ("p", C.c_void_p), ("i", C.c_void_p),
                ("x", C.c_void_p), ("z", C.c_void_p), ("nz", C.c_void_p), ("next", C.c_void_p),
                ("prev", C.c_void_p), ("nsuper", C.c_size_t), ("ssize", C.c_size_t),
                ("xsize", C.c_size_t), ("maxcsize", C.c_size_t), ("maxesize", C.c_size_t),
                ("super", C.c_void_p), ("pi", C.c_void_p), ("px", C.c_void_p), ("s", C.c_void_p),
                ("ordering", C.c_int), ("is_ll", C.c_int), ("is_super", C.c_int),
                ("is_monotonic", C.c_int), ("itype", C.c_int), ("xtype", C.c_int), ("dtype", C.c_int)]


_P = C.c_void_p
_SIGNATURES = {
    "SuiteSparse_version": (C.c_int, [_P]),
    "cholmod_start": (C.c_int, [_P]),
    "cholmod_finish": (C.c_int, [_P]),
    "cholmod_analyze": (C.POINTER(_Factor), [_P, _P]),
    "cholmod_factorize": (C.c_int, [_P, _P, _P]),
    "cholmod_solve2": (C.c_int, [C.c_int, _P, _P, _P, _P, _P, _P, _P, _P]),
    "cholmod_free_factor": (C.c_int, [_P, _P]),
    "cholmod_free_dense": (C.c_int, [_P, _P]),
    "cholmod_copy_factor": (C.POINTER(_Factor), [_P, _P]),
    "cholmod_ptranspose": (C.POINTER(_Sparse), [_P, C.c_int, _P, _P, C.c_size_t, _P]),
    "cholmod_rowfac": (C.c_int, [_P, _P, _P, C.c_size_t, C.c_size_t, _P, _P]),
    "cholmod_free_sparse": (C.c_int, [_P, _P]),
    "cholmod_etree": (C.c_int, [_P, _P, _P]),
}

_lock = threading.Lock()
_library: list = []          # [] before the first look, then [CDLL or None]
_off = threading.local()     # .depth > 0 inside disabled()


def library():
    """The CHOLMOD library inside cholespy's extension module, if its layout is the one this
    module was written for (checked once per process); otherwise None, and None inside
    :func:`disabled`."""
    if getattr(_off, "depth", 0):
        return None
    with _lock:
        if not _library:
            _library.append(_load())
        return _library[0]


@contextlib.contextmanager
def disabled():
    """Within this block (on this thread) CPU factors are made by cholespy's constructor, as
    where the library is not usable: for benchmarks and tests that compare the two paths."""
    _off.depth = getattr(_off, "depth", 0) + 1
    try:
        yield
    finally:
        _off.depth -= 1


def _load():
    try:
        import cholespy
        paths = glob.glob(os.path.join(os.path.dirname(cholespy.__file__), "_cholespy_core*"))
        lib = C.CDLL(paths[0])
        for name, (res, args) in _SIGNATURES.items():
            fn = getattr(lib, name)
            fn.restype, fn.argtypes = res, args
    except (ImportError, OSError, IndexError, AttributeError):
        return None
    version = (C.c_int * 3)()
    lib.SuiteSparse_version(version)
    if version[0] != 5:
        return None
    common = _Common()
    if not lib.cholmod_start(C.byref(common)):
        return None
    try:
        ok = _defaults_ok(common)
    finally:
        lib.cholmod_finish(C.byref(common))
    return lib if ok else None


def _defaults_ok(c: _Common) -> bool:
    """Whether every default cholmod_start wrote (CHOLMOD 3.0's cholmod_defaults) reads back at
    this module's offsets: a shifted or resized field would show up in one of them."""
    m = c.method
    return (c.dbound == 0.0 and c.grow0 == 1.2 and c.grow1 == 1.2 and c.grow2 == 5
            and c.maxrank == 8 and c.supernodal_switch == 40.0 and c.supernodal == _AUTO
            and c.final_asis == 1 and c.final_super == 1 and c.final_ll == 0
            and c.final_pack == 1 and c.final_monotonic == 1 and c.final_resymbol == 0
            and list(c.zrelax) == [0.8, 0.1, 0.05] and list(c.nrelax) == [4, 16, 48]
            and c.prefer_upper == 1 and c.quick_return_if_not_posdef == 0
            and c.nmethods == 0 and c.postorder == 1 and c.default_nesdis == 0
            and m[0].ordering == _GIVEN and m[1].ordering == _AMD and m[2].ordering == _METIS
            and m[3].ordering == _NESDIS and m[0].nd_small == 200 and m[0].prune_dense == 10.0
            and m[0].prune_dense2 == -1.0 and m[0].nd_oksep == 1.0 and m[0].aggressive == 1
            and m[0].nd_compress == 1 and m[0].nd_camd == 1)


def _start(lib) -> _Common:
    """A started cholmod_common with the settings every factor here uses."""
    c = _Common()
    lib.cholmod_start(C.byref(c))
    c.print = 0                        # a failed trial shift is handled, not printed
    c.supernodal = _SIMPLICIAL
    # LDLᵀ (final_ll stays 0): 6-10% faster than LLᵀ on PSB meshes; definiteness is then
    # checked on D in CholmodFactor.factorize().
    return c


def _free(lib, common, factor, *dense) -> None:
    for d in dense:
        if d:
            lib.cholmod_free_dense(C.byref(d), C.byref(common))
    if factor:
        lib.cholmod_free_factor(C.byref(factor), C.byref(common))
    lib.cholmod_finish(C.byref(common))
