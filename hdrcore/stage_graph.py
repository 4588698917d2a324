"""A declared stage graph with caches that cannot go stale.

Each :class:`Stage` declares the parameter fields and the upstream stages it reads. Its function
is called with a :class:`ParamsView` that lets it read only the declared fields and an
:class:`Inputs` that hands it only the declared upstream values; reading anything else raises
:class:`UndeclaredDependency`. The cache key of a stage is derived from the same declaration:
the values of its fields (:func:`token`: a deterministic content token, never ``id()``) and the
tokens of its inputs. A dependency the key forgets is therefore one the function cannot read:
a forgotten dependency shows up as an error on the first run, not as a stale result.

An input's token is its own key (the value is a function of that key), or a content token of
its value when the stage says ``by_value`` (cheap values such as a tuple of ratios: a
downstream stage then re-runs only when the value really changed) or when the value is
``None`` (a stage switched off reads nothing, whatever its parameters). ``lazy`` inputs are
computed only when the function asks for them (a branch that is not taken costs nothing); they
enter the key by their declaration key, so the key is known before anything runs.

This is the approach of Dask's ``tokenize`` (a key from the content of the inputs) and of
Snakemake's rules (inputs declared, the rest derived); the pipeline's graph is in
:mod:`hdrcore.pipeline` (``GRAPH``) and ``ARCHITECTURE.md`` says how to add a stage.
"""

from __future__ import annotations

import dataclasses
import enum
import hashlib
import math
import pickle
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import PurePath
from typing import Any

import numpy as np

__all__ = [
    "Entry",
    "Inputs",
    "ParamsView",
    "Stage",
    "StageCache",
    "StageGraph",
    "UndeclaredDependency",
    "token",
]


class UndeclaredDependency(RuntimeError):
    """A stage read a parameter field or an upstream stage it does not declare (a bug in the
    stage's declaration, never a user error): add the name to the stage's ``params`` or
    ``inputs``."""


def token(value: Any) -> Any:
    """A hashable token of ``value``'s content: equal for equal content, whatever object holds
    it (never ``id()``). Numbers, strings, ``None``, containers, enums, paths and fractions are
    kept as values; numpy arrays become their dtype, shape and a BLAKE2 digest of their bytes;
    dataclasses the tokens of their fields; anything else a digest of its pickle (an object
    that cannot be pickled raises ``TypeError``: it has no content to key on)."""
    if value is None or isinstance(value, (bool, str, bytes)):
        return (type(value).__name__, value)
    if isinstance(value, enum.Enum):
        return ("enum", type(value).__qualname__, value.name)
    if isinstance(value, (int, np.integer)):
        return ("int", int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return ("float", "nan" if math.isnan(v) else v.hex())
    if isinstance(value, Fraction):
        return ("fraction", value.numerator, value.denominator)
    if isinstance(value, PurePath):
        return ("path", str(value))
    if isinstance(value, (tuple, list)):
        return ("seq", tuple(token(v) for v in value))
    if isinstance(value, dict):
        return (
            "map",
            tuple(sorted(((repr(k), token(v)) for k, v in value.items()), key=lambda kv: kv[0])),
        )
    if isinstance(value, (set, frozenset)):
        return ("set", tuple(sorted(repr(token(v)) for v in value)))
    if isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        digest = hashlib.blake2b(
            a.view(np.uint8).reshape(-1).data if a.size else b"", digest_size=20
        ).hexdigest()
        return ("array", a.dtype.str, a.shape, digest)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return (
            "dataclass",
            type(value).__module__,
            type(value).__qualname__,
            tuple((f.name, token(getattr(value, f.name))) for f in dataclasses.fields(value)),
        )
    try:
        data = pickle.dumps(value, protocol=5)
    except Exception as exc:  # no content to key on: never fall back on id()
        raise TypeError(f"cannot derive a cache token from a {type(value).__name__}") from exc
    return ("pickle", type(value).__qualname__, hashlib.blake2b(data, digest_size=20).hexdigest())


class ParamsView:
    """The fields of a parameter object a stage declared, read-only; any other field raises
    :class:`UndeclaredDependency`."""

    __slots__ = ("_fields", "_params", "_stage")

    def __init__(self, params: Any, fields: Iterable[str], stage: str) -> None:
        object.__setattr__(self, "_params", params)
        object.__setattr__(self, "_fields", frozenset(fields))
        object.__setattr__(self, "_stage", stage)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        if name not in self._fields:
            raise UndeclaredDependency(
                f"stage {self._stage!r} read the parameter {name!r}, which it does not declare "
                f"(it declares {', '.join(sorted(self._fields)) or 'none'}): add it to the "
                "stage's params"
            )
        return getattr(self._params, name)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("a stage's parameters are read-only")

    def __repr__(self) -> str:
        shown = ", ".join(f"{f}={getattr(self._params, f)!r}" for f in sorted(self._fields))
        return f"ParamsView({self._stage}: {shown})"


@dataclass(frozen=True)
class Stage:
    """One stage: ``fn(context, params, inputs)`` returns its value.

    ``params``: the parameter fields ``fn`` reads, or a function of the context (the bracket,
    fixed for a cache's life) returning them, for a stage that reads a field only for some
    inputs (the response reads the exposure method only when the frames carry no times).
    ``inputs``: upstream stages computed before ``fn`` runs; ``lazy``: upstream stages computed
    only if ``fn`` asks for them. ``by_value``: downstream keys use a content token of the value
    instead of this stage's key (for small values: a downstream stage re-runs only when the
    value changed). ``internal``: a step between the reported stages (no progress, no timing,
    not in ``stages_run``). ``keep``: how many values of different keys the cache keeps (the
    current one and the last ``keep - 1`` it replaced): going back to a key computed lately
    (a control moved and moved back, a reset) takes the value again instead of computing it;
    for stages whose values are small and slow to make.
    """

    name: str
    fn: Callable[[Any, ParamsView, Inputs], Any]
    params: tuple[str, ...] | Callable[[Any], tuple[str, ...]] = ()
    inputs: tuple[str, ...] = ()
    lazy: tuple[str, ...] = ()
    by_value: bool = False
    internal: bool = False
    doc: str = ""
    keep: int = 1

    def fields(self, context: Any) -> tuple[str, ...]:
        return tuple(self.params(context) if callable(self.params) else self.params)


class StageGraph:
    """The stages by name, checked once: unique names, declared inputs that exist, no cycle,
    static parameter fields that exist in ``param_fields``."""

    def __init__(self, stages: Iterable[Stage], param_fields: Iterable[str]) -> None:
        self.stages: dict[str, Stage] = {}
        self.param_fields = frozenset(param_fields)
        for st in stages:
            if st.name in self.stages:
                raise ValueError(f"stage {st.name!r} declared twice")
            self.stages[st.name] = st
        for st in self.stages.values():
            for name in (*st.inputs, *st.lazy):
                if name not in self.stages:
                    raise ValueError(f"stage {st.name!r} reads an unknown stage {name!r}")
            if not callable(st.params):
                self._check_fields(st, st.params)
        self.order = self._topological()

    def _check_fields(self, st: Stage, fields: Iterable[str]) -> None:
        unknown = [f for f in fields if f not in self.param_fields]
        if unknown:
            raise ValueError(f"stage {st.name!r} declares unknown parameters {unknown}")

    def _topological(self) -> tuple[str, ...]:
        order: list[str] = []
        state: dict[str, int] = {}

        def visit(name: str, path: tuple[str, ...]) -> None:
            if state.get(name) == 2:
                return
            if state.get(name) == 1:
                raise ValueError("stage cycle: " + " -> ".join((*path, name)))
            state[name] = 1
            st = self.stages[name]
            for up in (*st.inputs, *st.lazy):
                visit(up, (*path, name))
            state[name] = 2
            order.append(name)

        for name in self.stages:
            visit(name, ())
        return tuple(order)

    def upstream(self, name: str, skip: Iterable[str] = ()) -> set[str]:
        """Every stage ``name`` may read, directly or through others (not through the stages
        in ``skip``, which are left out with what only they read)."""
        seen: set[str] = set()
        todo = [name]
        left_out = set(skip)
        while todo:
            st = self.stages[todo.pop()]
            for up in (*st.inputs, *st.lazy):
                if up not in seen and up not in left_out:
                    seen.add(up)
                    todo.append(up)
        return seen

    def fields_read(self, name: str, context: Any, skip: Iterable[str] = ()) -> set[str]:
        """The parameter fields ``name``'s value depends on, its upstream stages' included
        (not those read only through the stages in ``skip``)."""
        out = set(self.stages[name].fields(context))
        for up in self.upstream(name, skip):
            out.update(self.stages[up].fields(context))
        return out


@dataclass
class Entry:
    """A cached value, the key it was computed for, its cost and its token downstream."""

    key: Any
    value: Any
    seconds: float
    token: Any


class Inputs:
    """The upstream values a stage declared, by attribute or ``[name]``; any other raises
    :class:`UndeclaredDependency`. Lazy ones are computed on first access."""

    __slots__ = ("_eager", "_lazy", "_run", "_stage")

    def __init__(self, stage: str, eager: dict[str, Any], lazy: tuple[str, ...], run: _Run) -> None:
        self._stage, self._eager, self._lazy, self._run = stage, eager, lazy, run

    def __getitem__(self, name: str) -> Any:
        if name in self._eager:
            return self._eager[name]
        if name in self._lazy:
            return self._run.get(name)
        raise UndeclaredDependency(
            f"stage {self._stage!r} read the stage {name!r}, which it does not declare: add it "
            "to the stage's inputs (or lazy inputs)"
        )

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return self[name]


class StageCache:
    """One value per stage of ``graph`` with the key it was computed for. ``context`` is what
    every stage may read besides its declared parameters and inputs: data fixed for the cache's
    life (the bracket). ``on_start(name)`` / ``on_done(name, seconds)`` are called around the
    computation of a reported (not internal) stage."""

    def __init__(
        self,
        graph: StageGraph,
        context: Any,
        *,
        on_start: Callable[[str], None] | None = None,
        on_done: Callable[[str, float], None] | None = None,
    ) -> None:
        self.graph = graph
        self.context = context
        self.entries: dict[str, Entry] = {}
        # per stage, the entries the current one replaced, newest first (Stage.keep - 1)
        self.recent: dict[str, list[Entry]] = {}
        self.on_start = on_start
        self.on_done = on_done

    def run(
        self, params: Any, ran: list[str] | None = None, timings: dict[str, float] | None = None
    ) -> _Run:
        """A run with ``params``: ``get(name)`` returns a stage's value (from the cache when its
        key is unchanged), appending the reported stages computed to ``ran`` and every reported
        stage's seconds to ``timings`` (0 for a cached one)."""
        return _Run(self, params, [] if ran is None else ran, {} if timings is None else timings)

    def pop(self, name: str) -> Entry | None:
        self.recent.pop(name, None)
        return self.entries.pop(name, None)

    def clear(self) -> None:
        self.entries.clear()
        self.recent.clear()

    def has(self, name: str, key: Any) -> bool:
        """Whether stage ``name``'s value of ``key`` is held (current or kept)."""
        entry = self.entries.get(name)
        if entry is not None and entry.key == key:
            return True
        return any(e.key == key for e in self.recent.get(name, ()))

    def recall(self, name: str, key: Any) -> Entry | None:
        """Stage ``name``'s kept entry of ``key``, made current again (the current one kept in
        its place), or ``None``."""
        older = self.recent.get(name)
        if not older:
            return None
        for i, e in enumerate(older):
            if e.key == key:
                del older[i]
                self._replace(name, e)
                return e
        return None

    def _replace(self, name: str, entry: Entry) -> None:
        """``entry`` becomes ``name``'s current one; the one it replaces is kept as recent
        (up to the stage's ``keep``)."""
        keep = self.graph.stages[name].keep
        old = self.entries.get(name)
        self.entries[name] = entry
        if keep > 1 and old is not None and old.key != entry.key:
            older = self.recent.setdefault(name, [])
            older.insert(0, old)
            del older[keep - 1 :]


class _Run:
    def __init__(
        self, cache: StageCache, params: Any, ran: list[str], timings: dict[str, float]
    ) -> None:
        self.cache, self.params, self.ran, self.timings = cache, params, ran, timings
        self._keys: dict[str, Any] = {}
        self._values: dict[str, Any] = {}  # the stages this run has resolved
        self._tokens: dict[str, Any] = {}
        self._fields: dict[str, Any] = {}  # parameter tokens (a curve is hashed once a run)
        self._child: list[float] = []  # seconds spent in nested reported stages, per level

    def key(self, name: str) -> Any:
        """The key of ``name`` for this run's parameters: its fields' values and its inputs'
        tokens (the eager inputs are computed to get them; the lazy ones enter by their key)."""
        if name in self._keys:
            return self._keys[name]
        graph = self.cache.graph
        st = graph.stages[name]
        fields = st.fields(self.cache.context)
        if callable(st.params):
            graph._check_fields(st, fields)
        key = (
            name,
            tuple((f, self.field_token(f)) for f in fields),
            tuple((up, self.token(up)) for up in st.inputs),
            tuple((up, ("key", self.key(up))) for up in st.lazy),
        )
        self._keys[name] = key
        return key

    def field_token(self, name: str) -> Any:
        if name not in self._fields:
            self._fields[name] = token(getattr(self.params, name))
        return self._fields[name]

    def token(self, name: str) -> Any:
        self.get(name)
        return self._tokens[name]

    def get(self, name: str, **extra: Any) -> Any:
        """The value of stage ``name``; ``extra`` keyword arguments go to its function and are
        no dependency (the merge's spare buffers: where the result is written, not what)."""
        if name in self._values:
            return self._values[name]
        cache = self.cache
        st = cache.graph.stages[name]
        key = self.key(name)
        entry = cache.entries.get(name)
        if entry is None or entry.key != key:
            entry = cache.recall(name, key)
        if entry is not None and entry.key == key:
            if not st.internal:
                self.timings[name] = 0.0
            self._values[name], self._tokens[name] = entry.value, entry.token
            return entry.value
        eager = {up: self.get(up) for up in st.inputs}
        if not st.internal and cache.on_start is not None:
            cache.on_start(name)
        view = ParamsView(self.params, st.fields(cache.context), name)
        self._child.append(0.0)
        t0 = time.perf_counter()
        try:
            value = st.fn(cache.context, view, Inputs(name, eager, st.lazy, self), **extra)
        finally:
            total = time.perf_counter() - t0
            nested = self._child.pop()
        dt = total - nested
        if self._child:
            self._child[-1] += total if not st.internal else nested
        tok = ("value", token(value)) if st.by_value or value is None else ("key", key)
        cache._replace(name, Entry(key, value, dt, tok))
        self._values[name], self._tokens[name] = value, tok
        if not st.internal:
            self.timings[name] = dt
            self.ran.append(name)
            if cache.on_done is not None:
                cache.on_done(name, dt)
        return value
