"""Stored programs verify themselves: a damaged, truncated or swapped file is discarded
and traced again with one warning, never a failed call or a wrong result."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxenvs import program_cache


def _affine(x: jax.Array) -> jax.Array:
    # constants in the module: a flipped byte in one of them would change the result
    return x * jnp.float32(3.25) + jnp.arange(8, dtype=jnp.float32)


def _square(x: jax.Array) -> jax.Array:
    return x * x


X = jnp.linspace(-1.0, 1.0, 8, dtype=jnp.float32)


def _store(directory: Path, fn=_affine, name: str = "affine") -> program_cache.Program:
    return program_cache.load_or_export(fn, (X,), name=name, config={}, directory=directory)


def _only_file(directory: Path, name: str = "affine") -> Path:
    (path,) = directory.glob(f"{name}-*.jaxexport")
    return path


def _damaged_then_healed(directory: Path, fn=_affine, name: str = "affine") -> None:
    """The store, with a damaged file in ``directory``: warns once, returns a program that
    gives the right result, and the next load reads the rebuilt file."""
    with pytest.warns(UserWarning, match="damaged stored program") as record:
        program = _store(directory, fn, name)
    assert len([w for w in record if "damaged" in str(w.message)]) == 1
    assert not program.loaded
    np.testing.assert_array_equal(program.call(X), jax.jit(fn)(X))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = _store(directory, fn, name)
    assert again.loaded
    np.testing.assert_array_equal(again.call(X), jax.jit(fn)(X))


@pytest.mark.parametrize("where", [0, 20, 60, 0.5, -40, -1])
def test_flipped_byte_anywhere_is_caught(tmp_path, where):
    _store(tmp_path)
    path = _only_file(tmp_path)
    blob = bytearray(path.read_bytes())
    i = int(where * len(blob)) if isinstance(where, float) else where
    blob[i] ^= 0x01
    path.write_bytes(bytes(blob))
    _damaged_then_healed(tmp_path)


@pytest.mark.parametrize("keep", [0, 10, 0.5, -1])
def test_truncated_file_is_caught(tmp_path, keep):
    _store(tmp_path)
    path = _only_file(tmp_path)
    blob = path.read_bytes()
    n = int(keep * len(blob)) if isinstance(keep, float) else keep % len(blob)
    path.write_bytes(blob[:n])
    _damaged_then_healed(tmp_path)


def test_file_of_another_key_is_caught(tmp_path):
    """A valid file copied over another key's file (same name prefix, same signature)."""
    _store(tmp_path)
    _store(tmp_path, _square, "square")
    affine, square = _only_file(tmp_path), _only_file(tmp_path, "square")
    square_name = square.name
    square.write_bytes(affine.read_bytes())
    assert (tmp_path / square_name).exists()
    _damaged_then_healed(tmp_path, _square, "square")


def _repack(directory: Path, edit) -> None:
    """Rewrite the stored file with ``edit(module bytes)`` and a valid key and digest, as
    a writer with a bug (not damage on disk) would leave it."""
    path = _only_file(directory)
    key = path.stem.rsplit("-", 1)[1]
    header, module = program_cache._unpack(path.read_bytes(), key)
    path.write_bytes(program_cache._pack(key, header["name"], header["out"], edit(module)))


def test_module_that_does_not_deserialise_is_caught(tmp_path):
    _store(tmp_path)
    _repack(tmp_path, lambda module: module[: len(module) // 2])
    _damaged_then_healed(tmp_path)


def test_stablehlo_that_does_not_deserialise_is_caught(tmp_path):
    """The failure the store once let through to the first call: ``Failed to deserialize
    StableHLO``, raised while lowering, now inside the fallback."""

    def garbage_stablehlo(module: bytes) -> bytes:
        exported = jax.export.deserialize(bytearray(module))
        broken = dataclasses.replace(exported, mlir_module_serialized=b"ML\xefR garbage")
        return bytes(broken.serialize())

    _store(tmp_path)
    _repack(tmp_path, garbage_stablehlo)
    _damaged_then_healed(tmp_path)


def test_file_carries_its_key_and_digest(tmp_path):
    _store(tmp_path)
    path = _only_file(tmp_path)
    key = path.stem.rsplit("-", 1)[1]
    header, _ = program_cache._unpack(path.read_bytes(), key)
    assert header["key"] == key
    with pytest.raises(program_cache.DamagedProgram, match="another key"):
        program_cache._unpack(path.read_bytes(), "0" * 64)


def test_unwritable_store_still_runs(tmp_path):
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    with pytest.warns(UserWarning, match="could not store program"):
        program = _store(blocker / "programs")
    np.testing.assert_array_equal(program.call(X), jax.jit(_affine)(X))
