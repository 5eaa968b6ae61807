"""The kernel table of tasks/warm.py: its notation round-trips numba's types, every row names a
compiled kernel with a signature numba accepts, and the shares split the work without repeats."""

from __future__ import annotations

import importlib

import pytest
from motionweb.tasks.warm import GROUPS, format_type, kernels, parse_type, shares


@pytest.mark.parametrize("token", ["f4", "f8", "i8", "i4", "u1", "b1", "f4[:,:]", "i8[:]", "u1[:]r",
                                   "f8[:,:,:]", "list(i4[:,:])"])
def test_notation_round_trips(token):
    assert format_type(parse_type(token)) == token


def test_notation_is_numbas():
    from numba.core import types as nt

    assert parse_type("f4[:,:]") == nt.Array(nt.float32, 2, "C")
    assert parse_type("u1[:]r") == nt.Array(nt.uint8, 1, "C", readonly=True)
    assert parse_type("i8") == nt.int64
    assert format_type(nt.Array(nt.float64, 2, "F")).startswith("?")  # not written: never guessed


@pytest.mark.parametrize("bad", ["f3", "q8[:]", "f4[:,:", "list(f4", ""])
def test_bad_token_names_itself(bad):
    with pytest.raises(ValueError, match="kernel signature token"):
        parse_type(bad)


def test_every_row_is_a_cached_kernel_with_a_valid_signature():
    for module, name, signature, seconds in kernels(sorted(GROUPS)):
        kernel = getattr(importlib.import_module(module), name)
        assert type(kernel._cache).__name__ == "FunctionCache", f"{module}.{name}: not cache=True, a warm-up cannot keep it"
        args = [parse_type(t) for t in signature.split()]
        assert len(args) == kernel.py_func.__code__.co_argcount, f"{module}.{name}: {len(args)} argument types"
        assert seconds > 0


@pytest.mark.parametrize("n", [1, 2, 3, 8])
def test_shares_cover_each_row_once_and_keep_modules_together(n):
    rows = kernels(["read", "index", "search"])
    parts = shares(["read", "index", "search"], n)
    assert 1 <= len(parts) <= n
    assert sorted(r for p in parts for r in p) == sorted(rows)
    modules = [{r[0] for r in p} for p in parts]
    assert sum(len(m) for m in modules) == len(set().union(*modules))  # no module in two shares
    if n == 2:  # longest-first: neither share holds more than the other plus its largest module
        load = sorted(sum(r[3] for r in p) for p in parts)
        assert load[1] - load[0] <= max(sum(r[3] for r in rows if r[0] == m) for m in {r[0] for r in rows})


def test_unknown_group_is_named():
    with pytest.raises(ValueError, match="unknown kernel groups \\['nope'\\]"):
        kernels(["index", "nope"])
