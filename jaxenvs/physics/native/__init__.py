"""The native engine: MuJoCo's C engine as an XLA FFI call (``engine.cc`` beside this file).

``pip install`` compiles ``engine.cc`` (``setup.py``) against the headers of jaxlib's XLA FFI
and MuJoCo's batched API (``mujoco/mjbatch.h``), into ``_engine*.so`` here, with the
versions it was built against compiled in. :func:`library` loads it once per process
and registers its handler with JAX as the CPU target :data:`TARGET`.

The library is used only if it loads and was built against the MuJoCo and jaxlib this
process has. Otherwise :func:`library` returns ``None``, :func:`unavailable_reason` says why
in one line that names the fix, and :mod:`jaxenvs.physics.cengine` steps through a Python callback
with the same results. ``JAXENVS_NATIVE=0`` turns the native engine off (for tests and for
comparing the two paths).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import importlib.metadata
import os
import warnings
from pathlib import Path

import numpy as np

#: the FFI target name the handler is registered under
TARGET = "jaxenvs_mj_step"
#: set to 0 to step the C engine through the Python callback
ENV_VAR = "JAXENVS_NATIVE"
_HERE = Path(__file__).resolve().parent
_FIX = (
    "reinstall jaxenvs where a C++ compiler is available "
    "(pip install --force-reinstall --no-deps -e <jaxenvs checkout>, or without -e)"
)
_reason: list[str] = []  # why library() returned None, once it has


def _built_file() -> Path | None:
    found = sorted(_HERE.glob("_engine*.so"))
    return found[-1] if found else None


def installed_version(name: str) -> str | None:
    """The installed version of distribution ``name``, or ``None`` where it is not
    installed."""
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def _open() -> ctypes.CDLL | str:
    """The built library, loaded, or why not (one line that names the fix)."""
    path = _built_file()
    if path is None:
        return f"the native engine was not built at install (no C++ compiler?): {_FIX}"
    import mujoco  # noqa: F401  (its bindings load libmujoco, which ours links by soname)

    try:
        return ctypes.CDLL(str(path))
    except OSError as err:
        return f"the native engine at {path.name} does not load ({err}): {_FIX}"


@functools.lru_cache(maxsize=1)
def library() -> ctypes.CDLL | None:
    """The loaded native engine with its FFI target registered, or ``None``."""
    if os.environ.get(ENV_VAR, "1").strip().lower() in ("0", "false", "no", "off"):
        _reason.append(f"{ENV_VAR}=0 turns the native engine off")
        return None
    import jax
    import mujoco

    lib = _open()
    if isinstance(lib, str):
        _reason.append(lib)
        return None
    lib.jaxenvs_register_model.argtypes = [
        ctypes.c_char_p,
        ctypes.c_void_p,
        ctypes.c_char_p,
        ctypes.c_int,
    ]
    lib.jaxenvs_register_model.restype = ctypes.c_int
    lib.jaxenvs_built_versions.restype = ctypes.c_char_p
    built = dict(
        zip(("jaxlib", "mujoco"), lib.jaxenvs_built_versions().decode().split(), strict=False)
    )
    for name in ("jaxlib", "mujoco"):
        have = installed_version(name)
        if built.get(name) != have:
            _reason.append(
                f"the native engine was built against {name} {built.get(name)}, this process "
                f"has {name} {have}: {_FIX}"
            )
            return None
    if lib.jaxenvs_mujoco_header_version() != mujoco.mj_version():
        _reason.append(f"the native engine's MuJoCo headers are not this process's: {_FIX}")
        return None
    jax.ffi.register_ffi_target(
        TARGET, jax.ffi.pycapsule(lib.JaxenvsMjStep), platform="cpu", api_version=1
    )
    _learn_default_clock(lib)
    return lib


#: the model ``<numeric>`` (value 1) that asks MuJoCo C for jaxenvs' heightfield collider
HFIELD_SURFACE = "jaxenvs_hfield_surface"


@functools.lru_cache(maxsize=1)
def hfield_surface() -> str | None:
    """Install jaxenvs' sphere-on-heightfield collider in MuJoCo C (``hfield.cc`` beside
    this file) and return the name of the model ``<numeric>`` that asks for it
    (:data:`HFIELD_SURFACE`); ``None`` where the library is not built or not built for this
    process's MuJoCo.

    Installed once per process in MuJoCo's collision table, for every MuJoCo C step of the
    process, native or through the Python callback (``JAXENVS_NATIVE`` does not turn it
    off); a model without the numeric keeps MuJoCo's own collider.
    """
    import mujoco

    lib = _open()
    if isinstance(lib, str) or lib.jaxenvs_mujoco_header_version() != mujoco.mj_version():
        return None
    try:
        install = lib.jaxenvs_install_hfield_surface
    except AttributeError:  # a library built before the collider: not rebuilt since
        return None
    install.restype = ctypes.c_char_p
    name = install().decode()
    if name != HFIELD_SURFACE:
        raise RuntimeError(f"the native library asks for {name!r}, not {HFIELD_SURFACE!r}")
    return name


def wants_hfield_surface(model: object) -> bool:
    """True if ``model`` (a :class:`mujoco.MjModel`) asks for the heightfield collider."""
    import mujoco

    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, HFIELD_SURFACE)
    if i < 0 or model.numeric_size[i] < 1:  # type: ignore[attr-defined]
        return False
    return float(model.numeric_data[model.numeric_adr[i]]) != 0  # type: ignore[attr-defined]


def prepare(model: object) -> None:
    """Ready MuJoCo C for stepping ``model``: install the heightfield collider if it asks
    for it (:func:`hfield_surface`), or warn, once a process, that MuJoCo's own collider
    steps it (the native library is not built)."""
    if wants_hfield_surface(model) and hfield_surface() is None:
        _warn_no_surface()


@functools.lru_cache(maxsize=1)
def _warn_no_surface() -> None:
    warnings.warn(
        "a model asks for jaxenvs' heightfield collider (hfield_contact='surface') but the "
        "native library is not built for this MuJoCo: MuJoCo C collides its feet with the "
        "heightfield's prisms instead (tilted normals on flat cells, docs/terrain.md). " + _FIX,
        RuntimeWarning,
        stacklevel=4,
    )


def _learn_default_clock(lib: ctypes.CDLL) -> None:
    """Tell the engine which ``mjcb_time`` is the Python bindings' default clock.

    The bindings install it at import (and again on ``mujoco.set_mjcb_time(None)``), which
    turns on MuJoCo's per-stage timers (``mjData.timer``) process-wide: a quarter of a
    small model's step. Native calls turn it off (engine.cc, ``QuietDefaultClock``); a
    clock set with ``mujoco.set_mjcb_time(fn)`` is another pointer and stays.
    """
    import mujoco

    lib.jaxenvs_clock.restype = ctypes.c_void_p
    lib.jaxenvs_set_clock.argtypes = [ctypes.c_void_p]
    lib.jaxenvs_set_default_clock.argtypes = [ctypes.c_void_p]
    users = mujoco.get_mjcb_time()
    saved = lib.jaxenvs_clock()
    mujoco.set_mjcb_time(None)  # the bindings' default
    default = lib.jaxenvs_clock()
    if users is not None:
        mujoco.set_mjcb_time(users)
    else:
        lib.jaxenvs_set_clock(saved)
    if default:
        lib.jaxenvs_set_default_clock(default)


def available() -> bool:
    """True if the native engine is loaded (or loads now)."""
    return library() is not None


def unavailable_reason() -> str | None:
    """One line on why the native engine is not used, naming the fix; ``None`` if it is."""
    return None if available() else _reason[-1]


def model_key(model: object) -> str:
    """A digest of ``model``'s content (its MJB serialisation): the same in every process
    that builds the same model, so a compiled program that names it can be cached."""
    import mujoco

    buffer = np.zeros(mujoco.mj_sizeModel(model), np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    return "mjb-" + hashlib.sha256(buffer.tobytes()).hexdigest()[:32]


def register_model(model: object) -> str:
    """Give the native engine its own copy of ``model``; returns the key calls name it by."""
    lib = library()
    if lib is None:
        raise RuntimeError(unavailable_reason())
    key = model_key(model)
    error = ctypes.create_string_buffer(256)
    address = model._address  # type: ignore[attr-defined]
    if lib.jaxenvs_register_model(key.encode(), address, error, len(error)):
        raise RuntimeError(f"jaxenvs native engine: {error.value.decode()}")
    return key
