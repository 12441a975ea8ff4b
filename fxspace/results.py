"""One vocabulary for how an iterative routine ended (after optimistix's ``RESULTS``).

Every iterative routine in fxspace (fuzzy c-means, sparse FCM, kernel k-means, fused
lasso, control-point fitting, IK solvers and tracking, registration, …) returns a
result record that carries

- ``.result``: a member of `RESULTS` (an ``equinox.Enumeration`` item, so it is
  a pytree leaf that survives ``jit`` and ``vmap``; compare with ``==``:
  ``res.result == fx.RESULTS.successful`` is a boolean array);
- ``.num_steps``: the iterations run (int array);
- ``.stats``: a ``dict`` of scalar diagnostics (at least ``"max_steps"``; solvers add
  their residual or objective there).

and takes ``throw: bool`` (default ``False``, so sweeps under ``vmap`` keep going and
report per element). With ``throw=True`` a result other than ``successful`` raises
`FxspaceError` with a one-line message naming the routine and the
cause; under ``jit`` the same check runs through ``equinox.error_if`` (an
``EquinoxRuntimeError`` with the same message, since nothing else can leave a
compiled computation).

**Example:**

```python
import fxspace as fx
res = fx.fuzzy_cmeans(X, 4, key=key)
if res.result != fx.RESULTS.successful:
    print(fx.RESULTS[res.result])       # the message
fx.fuzzy_cmeans(X_with_nan, 4, key=key, throw=True)   # FxspaceError: fuzzy_cmeans: ...
```
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from fxspace.errors import FxspaceError

__all__ = [
    "RESULTS",
    "check_result",
    "is_successful",
    "result_code",
    "member_code",
    "result_from_code",
    "result_from_flags",
    "result_message",
    "result_messages",
    "where_result",
]


class RESULTS(eqx.Enumeration):
    """How an iterative routine ended. The value of each member is its message."""

    successful = ""
    max_steps_reached = (
        "the iteration limit was reached before the tolerance was met; raise max_steps "
        "or loosen the tolerance"
    )
    nonfinite_input = (
        "the input holds NaN or inf; fill short gaps (fx.fill_gaps) or drop the "
        "missing frames/markers first"
    )
    nonfinite_output = (
        "the iteration produced NaN or inf; check the scale of the input (rescale to "
        "unit size) or the step size"
    )
    stalled = (
        "the solver could make no further progress before meeting its tolerance (a "
        "line search or damping step failed); loosen the tolerance or start elsewhere"
    )
    disconnected = (
        "the neighbourhood graph is disconnected; raise the threshold or drop the isolated frames"
    )
    poor_fit = (
        "the solve finished but the model does not fit the data (residual large for the "
        "model's scale, or outlying markers); check the units, the marker names and order, "
        "and the frames and markers the record names"
    )


class _ResultItem(type(RESULTS.successful)):  # type: ignore[misc]
    """A `RESULTS` member that prints as one: ``RESULTS.successful``, or for a batch the
    count of each member (``RESULTS[successful ×98, max_steps_reached ×2]``); ``str``
    adds the message of a scalar failure. Only printing differs from equinox's item
    (same fields, so the same pytree leaves under jit/vmap)."""

    def _names(self) -> list[str] | None:
        (leaf,) = jax.tree_util.tree_leaves(self)
        if isinstance(leaf, jax.core.Tracer):
            return None
        names = {member_code(getattr(RESULTS, n)): n for n in _MEMBERS}
        return [names.get(int(c), f"code {int(c)}") for c in np.asarray(leaf).reshape(-1)]

    def _scalar(self) -> bool:
        (leaf,) = jax.tree_util.tree_leaves(self)
        return np.ndim(leaf) == 0

    def __repr__(self) -> str:
        names = self._names()
        if names is None:
            return "RESULTS<traced>"
        if self._scalar():
            return f"RESULTS.{names[0]}"
        counts = {n: names.count(n) for n in dict.fromkeys(names)}
        return "RESULTS[" + ", ".join(f"{n} ×{c}" for n, c in counts.items()) + "]"

    def __str__(self) -> str:
        names = self._names()
        if names is None or not self._scalar() or names[0] == "successful":
            return repr(self)
        return f"{repr(self)}: {RESULTS[self]}"


def _readable(item: Any) -> Any:
    """``item`` (a `RESULTS` member, any shape) as a `_ResultItem`."""
    if isinstance(item, _ResultItem):
        return item
    (leaf,) = jax.tree_util.tree_leaves(item)
    return _ResultItem(leaf, RESULTS)


_MEMBERS = (
    "successful",
    "max_steps_reached",
    "nonfinite_input",
    "nonfinite_output",
    "stalled",
    "disconnected",
    "poor_fit",
)
# the members, and every member `RESULTS.where` builds, print readably (`_ResultItem`)
_where = RESULTS.where
for _n in _MEMBERS:
    RESULTS._name_to_item[_n] = _readable(RESULTS._name_to_item[_n])
RESULTS.where = classmethod(lambda cls, pred, a, b: _readable(_where(pred, a, b)))
del _n


def result_message(result: Any) -> str:
    """The message of a concrete scalar result (``""`` for ``successful``); same as
    ``RESULTS[result]``."""
    return RESULTS[result]


def is_successful(result: Any) -> jax.Array:
    """``result == RESULTS.successful`` as a boolean array (works under jit/vmap)."""
    return result == RESULTS.successful


def result_code(result: Any) -> jax.Array:
    """The integer code(s) of a `RESULTS` item (any batch shape): its one pytree leaf,
    read through the public pytree API (never equinox's private fields)."""
    (leaf,) = jax.tree_util.tree_leaves(result)
    return jnp.asarray(leaf)


def member_code(item: Any) -> int:
    """A `RESULTS` member's integer code, read on the host with numpy: safe while tracing
    and at import time (a ``jnp`` op there would start the XLA backend, which must wait
    for ``jax.distributed.initialize``)."""
    (leaf,) = jax.tree_util.tree_leaves(item)
    return int(np.asarray(leaf))


def result_from_code(code: int) -> Any:
    """The `RESULTS` member whose integer code is ``code`` (as `member_code` reads it), for
    records stored as plain numbers (``.npz`` caches)."""
    for n in _MEMBERS:
        if member_code(getattr(RESULTS, n)) == int(code):
            return getattr(RESULTS, n)
    raise FxspaceError(f"no RESULTS member has code {code!r}; codes: {sorted(result_messages())}")


def result_messages() -> dict[int, str]:
    """``{code: message}`` for every `RESULTS` member (``""`` for ``successful``); safe
    to call while tracing (the codes are read on the host)."""
    return {member_code(getattr(RESULTS, n)): RESULTS[getattr(RESULTS, n)] for n in _MEMBERS}


def where_result(pred: Any, a: Any, b: Any) -> Any:
    """``RESULTS.where`` for any shape of ``pred`` (elementwise, broadcasting): a batch
    of results (e.g. one per frame under ``vmap``) stays one enumeration item. Built from
    equinox's public ``RESULTS.where`` (scalar) mapped over the batch."""
    pred = jnp.asarray(pred, bool)
    shape = jnp.broadcast_shapes(pred.shape, result_code(a).shape, result_code(b).shape)
    if shape == ():
        return RESULTS.where(pred, a, b)

    def flat(item):
        return jax.tree_util.tree_map(lambda v: jnp.broadcast_to(v, shape).reshape(-1), item)

    out = jax.vmap(RESULTS.where)(jnp.broadcast_to(pred, shape).reshape(-1), flat(a), flat(b))
    return jax.tree_util.tree_map(lambda v: v.reshape(shape), out)


def result_from_flags(
    *,
    converged: Any,
    nonfinite_input: Any = False,
    nonfinite_output: Any = False,
    stalled: Any = False,
) -> Any:
    """Build a `RESULTS` member from boolean flags (jit/vmap safe).

    Priority: non-finite input, non-finite output, converged → ``successful``, stalled,
    otherwise ``max_steps_reached``.
    """
    r = where_result(stalled, RESULTS.stalled, RESULTS.max_steps_reached)
    r = where_result(converged, RESULTS.successful, r)
    r = where_result(nonfinite_output, RESULTS.nonfinite_output, r)
    return where_result(nonfinite_input, RESULTS.nonfinite_input, r)


def _is_concrete(x: Any) -> bool:
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def check_result(result: Any, throw: bool, what: str, value: Any = None) -> Any:
    """Raise when ``throw`` and ``result`` is not ``successful``; return ``value``.

    Outside ``jit`` this raises `FxspaceError` (``"WHAT: message"``, naming the
    first failing element of a batch). Under ``jit`` it threads ``value`` through
    ``equinox.error_if`` so the compiled computation raises with the same message.
    With ``throw=False`` it returns ``value`` unchanged.
    """
    if not throw:
        return value
    if _is_concrete(result):
        raw = np.asarray(result_code(result))
        bad = np.flatnonzero(raw.reshape(-1) != member_code(RESULTS.successful))
        if bad.size:
            idx = int(bad[0])
            code = int(raw.reshape(-1)[idx])
            where = f" (element {idx} of {raw.size})" if raw.ndim else ""
            msg = result_messages()[code]
            raise FxspaceError(f"{what}: {msg}{where}")
        return value
    if value is None:
        return value
    for code, msg in result_messages().items():
        if not msg:
            continue
        pred = jnp.any(result_code(result) == code)
        value = eqx.error_if(value, pred, f"{what}: {msg}")
    return value
