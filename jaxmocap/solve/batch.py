"""Many sequences at once: padding, chunks that fit the device, sharding, per-sequence status.

Sequences of different lengths are padded to the longest (repeating their last frame,
so every padded value stays finite) and carry a (B, T) frame mask; padded frames drop
out of every term and keep their initial value. A batch runs as a `vmap`ped `solve`:
each element stops updating when it has converged, but a chunk runs until its slowest
element is done (a `while_loop` under `vmap`).

Memory: the normal equations of one sequence take O(T (2b+1) n²) bytes, so B sequences
of 1000 frames do not fit one GPU at once (SIP, B = 1000: 58.7 GiB asked for in one
buffer). `solve_batch` therefore estimates the bytes per sequence (`plan_batch`: T, the
unknowns per frame, the band, the residual rows, the dtypes), reads the device's free
memory and runs the batch in equal chunks; the last chunk is padded by repeating its
last member, so every chunk has one shape and one compiled program serves them all.

Devices: with several local devices each owns a contiguous block of the batch and
solves it chunk by chunk with the same single-device program, dispatched
asynchronously, so the devices run at once and each `while_loop` waits only for its
own members (no communication); the result is one array per leaf, split along the
batch over a one-axis mesh (`NamedSharding(Mesh(devices, ("batch",)), P("batch"))`).
An SPMD `shard_map` of the vmapped solve hung on two host-platform CPU devices, and
per-device dispatch needs no collective at all. Several processes (`jax.distributed`)
do not share a solve: their work (sweep cells) is independent, so each process solves
its own share on its local devices (see `jaxmocap.app.sweep`).
"""

from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from .._checks import check_weight
from .linearisation import Args
from .solver import Solution, check_inputs, prepare, solve_unjitted

__all__ = [
    "pad_sequences",
    "solve_batch",
    "with_weights",
    "BatchPlan",
    "plan_batch",
    "bytes_per_sequence",
    "free_memory_bytes",
    "length_buckets",
]

#: Multiplier on the counted buffers for XLA's temporaries (linearisation tangents,
#: the damped copy of H during a rejected step, the while_loop's double buffers).
#: SIP, T = 1000, one H200: the counted buffers are 190 MiB per sequence and the
#: device's peak was 19.0 GiB for chunks of 112, i.e. ≤ 174 MiB per sequence with all
#: inputs and outputs included (benchmarks/results/sweep_scale.json); 1.5 keeps a margin.
MEMORY_OVERHEAD = 1.5


def pad_sequences(sequences: Sequence[Any], length: int | None = None) -> tuple[Any, Array]:
    """Stack pytrees whose leaves are (T_i, ...) into (B, T, ...) plus a (B, T) frame mask.

    Every leaf is treated as per-frame (frame axis first) and padded by repeating its
    last frame. Per-sequence constants that are not per-frame belong in the `Problem`
    (closed over by the term functions) or must be stacked by the caller.
    """
    lengths = []
    for seq in sequences:
        Ts = {jnp.shape(x)[0] for x in jax.tree_util.tree_leaves(seq)}
        if len(Ts) != 1:
            raise ValueError(f"every leaf of a sequence must share its frame axis; got lengths {sorted(Ts)}.")
        lengths.append(Ts.pop())
    T = max(lengths) if length is None else length
    if T < max(lengths):
        raise ValueError(f"length={length} is shorter than the longest sequence ({max(lengths)}).")

    def pad(x, Ti):
        x = jnp.asarray(x)
        return jnp.concatenate([x, jnp.repeat(x[-1:], T - Ti, axis=0)], 0) if T > Ti else x

    padded = [jax.tree_util.tree_map(lambda x, Ti=Ti: pad(x, Ti), seq) for seq, Ti in zip(sequences, lengths)]
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *padded)
    mask = jnp.arange(T)[None, :] < jnp.asarray(lengths)[:, None]
    return stacked, mask


def length_buckets(lengths: Sequence[int], max_buckets: int = 4, multiple: int = 8) -> list[tuple[int, np.ndarray]]:
    """Group ragged sequence lengths into at most `max_buckets` padded lengths.

    Each bucket's length is a multiple of `multiple` (fewer distinct shapes, so fewer
    compilations); the boundaries are chosen by dynamic programming to minimise the
    total padded frames. Returns [(padded length, indices into `lengths`)], shortest first.
    """
    lengths = np.asarray(lengths, int)
    if lengths.ndim != 1 or not lengths.size or lengths.min() < 1:
        raise ValueError(f"lengths must be a non-empty list of positive frame counts, got {lengths.tolist()}.")
    if max_buckets < 1 or multiple < 1:
        raise ValueError(f"max_buckets and multiple must be >= 1, got {max_buckets}, {multiple}.")
    rounded = -(-lengths // multiple) * multiple
    cands = np.unique(rounded)  # candidate bucket lengths, ascending
    counts = np.array([(rounded == c).sum() for c in cands])
    k = len(cands)
    # dp[m][j]: fewest padded frames for candidates 0..j-1 in m buckets, each bucket
    # padded to its largest candidate; cut[m][j] where its last bucket starts.
    INF = float("inf")
    dp = [[INF] * (k + 1) for _ in range(max_buckets + 1)]
    cut = [[-1] * (k + 1) for _ in range(max_buckets + 1)]
    dp[0][0] = 0
    for m in range(1, max_buckets + 1):
        for j in range(1, k + 1):
            for i in range(j):
                if dp[m - 1][i] == INF:
                    continue
                c = dp[m - 1][i] + int(counts[i:j].sum()) * int(cands[j - 1])
                if c < dp[m][j]:
                    dp[m][j], cut[m][j] = c, i
    m = min(range(1, max_buckets + 1), key=lambda m: (dp[m][k], m))
    edges, j = [], k
    while j > 0:
        i = cut[m][j]
        edges.append((i, j))
        j, m = i, m - 1
    out = []
    for i, j in reversed(edges):
        length = int(cands[j - 1])
        members = np.flatnonzero((rounded > (cands[i - 1] if i else 0)) & (rounded <= length))
        out.append((length, members))
    return out


def with_weights(problem, weights: dict | None):
    """`problem` with the named terms' weights replaced (arrays: traced, no recompilation)."""
    if not weights:
        return problem
    names = {t.name for t in problem.terms}
    unknown = sorted(set(weights) - names)
    if unknown:
        raise ValueError(f"weights for terms {unknown} that the problem lacks; its terms are {sorted(names)}.")
    terms = [eqx.tree_at(lambda t: t.weight, t, weights[t.name]) if t.name in weights else t for t in problem.terms]
    return eqx.tree_at(lambda p: p.terms, problem, tuple(terms))


# --- memory plan -----------------------------------------------------------------------


def _nbytes(tree) -> int:
    return sum(int(np.prod(np.shape(x))) * np.dtype(getattr(x, "dtype", np.float32)).itemsize
               for x in jax.tree_util.tree_leaves(tree) if eqx.is_array_like(x))  # fmt: skip


def bytes_per_sequence(problem, params0: dict, data: Any = None, frame_mask=None, dtype=None,
                       factor_dtype=None, overhead: float = MEMORY_OVERHEAD) -> int:  # fmt: skip
    """Device bytes one sequence of a batched solve needs (an estimate, from shapes only).

    Counts, for T frames of n unknowns (band b, W windows of n_W, n_G per sequence) and
    m residual rows per frame: the Jacobian blocks T (2b+1) m n, the banded H and its
    factor 2 T (2b+1) n² (factor dtype), the border T n (W n_W + n_G), the residuals
    and the inputs, times `overhead` for XLA's temporaries. `params0` and `data` are
    one sequence (no batch axis); nothing is compiled or run (`jax.eval_shape`).
    """
    layout, params0, frame_mask, dtype = check_inputs(problem, params0, data, frame_mask, dtype)
    fdtype = jnp.dtype(factor_dtype or (jnp.float64 if jax.config.jax_enable_x64 else dtype))
    shapes = jax.eval_shape(lambda p, d, m: problem.residuals(p, d, m), params0, data, frame_mask)
    T, n = layout.T, layout.n
    s, f = jnp.dtype(dtype).itemsize, fdtype.itemsize
    bw = problem.bandwidths
    jac = sum(T * (2 * bw[k] + 1) * (int(np.prod(r.shape)) // T) * n * s for k, r in shapes.items())
    rows = sum(int(np.prod(r.shape)) for r in shapes.values()) * s
    band = 2 * problem.bandwidth + 1
    normal = 2 * T * band * n * n * f
    border = T * n * (layout.num_windows * layout.size("window") + layout.size("sequence")) * f
    inputs = _nbytes(params0) + _nbytes(data) + (0 if frame_mask is None else T)
    return int(overhead * (jac + rows + normal + border) + 3 * inputs)


def free_memory_bytes(device=None) -> int:
    """Bytes free for new buffers on `device` (default: the first local device).

    Accelerators: the allocator's limit minus what is in use. CPU: the host's
    MemAvailable (Linux), else 4 GiB.
    """
    device = jax.local_devices()[0] if device is None else device
    stats = device.memory_stats() if device.platform != "cpu" else None
    if stats and "bytes_limit" in stats:
        return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 4 << 30


@dataclasses.dataclass(frozen=True)
class BatchPlan:
    """How `solve_batch` runs B sequences: chunk size, chunk count, devices, the estimate."""

    batch: int
    chunk_size: int
    num_chunks: int
    num_devices: int
    bytes_per_sequence: int
    free_bytes_per_device: int
    memory_fraction: float

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def plan_batch(problem, params0: dict, data: Any = None, frame_mask=None, *, chunk_size: int | str | None = "auto",
               devices=None, memory_fraction: float = 0.6, dtype=None, factor_dtype=None) -> BatchPlan:  # fmt: skip
    """The chunking `solve_batch` uses for batched `params0` (B, ...) on `devices`.

    chunk_size: "auto" (the largest chunk whose estimated bytes, split over the devices,
    fit `memory_fraction` of the smallest device's free memory), None (one chunk), or
    an int. Chunks are a multiple of the device count, at most B rounded up to it.
    """
    devices = list(jax.local_devices() if devices is None else devices)
    if not devices:
        raise ValueError("devices is empty; give at least one device.")
    if not 0 < memory_fraction <= 1:
        raise ValueError(f"memory_fraction must be in (0, 1], got {memory_fraction}.")
    leaves = jax.tree_util.tree_leaves(params0)
    if not leaves:
        raise ValueError("params0 is empty; give a dict of batched (B, ...) initial parameters.")
    B = int(jnp.shape(leaves[0])[0])
    D = len(devices)
    first = lambda t: jax.tree_util.tree_map(lambda x: x[0], t)  # noqa: E731
    per = bytes_per_sequence(problem, first(params0), first(data), None if frame_mask is None else frame_mask[0],
                             dtype, factor_dtype)  # fmt: skip
    free = min(free_memory_bytes(d) for d in devices)
    full = -(-B // D) * D
    if chunk_size == "auto":
        fit = max(1, int(memory_fraction * free) // max(per, 1))  # per device
        # As few chunks as fit, then as equal as possible: little padding in the last.
        chunks = -(-B // (fit * D))
        size = min(full, -(-B // (chunks * D)) * D)
    elif chunk_size is None:
        size = full
    elif isinstance(chunk_size, (int, np.integer)) and chunk_size >= 1:
        size = min(full, -(-int(chunk_size) // D) * D)
    else:
        raise ValueError(f"chunk_size must be 'auto', None or a positive int, got {chunk_size!r}.")
    return BatchPlan(B, size, -(-B // size), D, per, free, memory_fraction)


# --- the batched solve -----------------------------------------------------------------


def solve_batch(
    problem,
    params0: dict,
    data: Any,
    frame_mask: Array | None = None,
    *,
    solver: Any = None,
    weights: dict[str, Array] | None = None,
    max_steps: int = 100,
    dtype: Any = None,
    adjoint: Any = None,
    check_bandwidth: bool = False,
    chunk_size: int | str | None = "auto",
    devices: Sequence | None = None,
    memory_fraction: float = 0.6,
    **deprecated,
) -> Solution:
    """`solve` over a leading batch axis of `params0`, `data` and `frame_mask`.

    Args are those of `solve`, each with a leading batch axis B; the solver's `rtol` and
    `atol` may be scalars or (B,) arrays (per-sequence tolerances, e.g.
    `VonMarcardLM(rtol=jnp.array([1e-3, 1e-8]))`). `check_bandwidth` measures the first
    member. `weights` maps term names to (B,) weights, one per member: an ablation grid is
    a batch axis, one compilation.
    chunk_size, devices, memory_fraction: see `plan_batch` (default: chunks that fit
    60 % of the free memory of every local device, the batch split over all of them).
    Every leaf of `data` is batched (leading axis B); the devices share the sequences.
    Returns a `Solution` whose every field has the batch axis first.
    """
    for k, v in (weights or {}).items():
        check_weight(f"weights[{k!r}]", v)
    leaves = jax.tree_util.tree_leaves(params0)
    if not leaves:
        raise ValueError("params0 is empty; give a dict of batched (B, ...) initial parameters.")
    B = jnp.shape(leaves[0])[0]
    bad = [jnp.shape(x) for x in jax.tree_util.tree_leaves(data) if not jnp.shape(x) or jnp.shape(x)[0] != B]
    if bad:
        raise ValueError(f"every leaf of data needs the batch axis B={B} first; got leaves of shapes {bad[:3]}.")
    first = lambda t: jax.tree_util.tree_map(lambda x: x[0], t)  # noqa: E731
    layout, _, _, dtype, how = prepare(
        problem, first(params0), first(data), None if frame_mask is None else frame_mask[0], dtype, solver,
        deprecated, max_steps, check_bandwidth, "solve_batch",
    )  # fmt: skip
    params0 = {k: jnp.asarray(params0[k], dtype) for k in layout.keys}
    rtol = jnp.broadcast_to(how.rtol, (B,))
    atol = jnp.broadcast_to(how.atol, (B,))
    weights = {k: jnp.broadcast_to(jnp.asarray(v, dtype), (B,)) for k, v in (weights or {}).items()}
    with_weights(problem, weights and {k: v[0] for k, v in weights.items()})  # names checked here
    if frame_mask is not None:
        frame_mask = jnp.asarray(frame_mask, bool)
    max_steps = how.max_steps
    static = dict(solver=how.solver, factor_dtype=how.factor_dtype, tridiagonal=how.tridiagonal, adjoint=adjoint)
    devices = tuple(jax.local_devices() if devices is None else devices)
    plan = plan_batch(problem, params0, data, frame_mask, chunk_size=chunk_size, devices=devices,
                      memory_fraction=memory_fraction, dtype=dtype, factor_dtype=how.factor_dtype)  # fmt: skip
    batched = (params0, data, frame_mask, weights, rtol, atol)
    if len(devices) == 1 and plan.num_chunks == 1 and plan.chunk_size == B:
        return _batch_jit(problem, layout, *batched, max_steps, **static)
    D, size = len(devices), plan.chunk_size
    per = size // D  # members per device and chunk
    # Device d owns the contiguous members [d·n, (d+1)·n) of the batch padded to n·D
    # (repeating the last member), and solves them in chunks of `per`: every call has
    # one shape, so each device compiles once, and no device waits for another.
    n = plan.num_chunks * per
    # Every device's block (and the problem's constants and step cap) is gathered and
    # sent before any solve is queued: a gather queued on the source device behind that
    # device's first solve would hold the other devices idle until it finished.
    blocks, consts = [], []
    for d, device in enumerate(devices):
        idx = jnp.asarray(np.minimum(np.arange(d * n, (d + 1) * n), B - 1))
        block = jax.tree_util.tree_map(lambda x, idx=idx: x[idx], batched)
        blocks.append(block if D == 1 else _to_device(block, device))
        consts.append((problem, max_steps) if D == 1 else _to_device((problem, max_steps), device))

    def run(d):
        prob, steps = consts[d]
        chunks = [
            jax.tree_util.tree_map(lambda x, k=k: x[k * per : (k + 1) * per], blocks[d]) for k in range(plan.num_chunks)
        ]
        return [_batch_jit(prob, layout, *chunk, steps, **static) for chunk in chunks]

    # One host thread per device: on GPU the host waits on every LM iteration's loop
    # condition, so a single thread would run the devices one after the other (measured
    # 0.91x on two H200s).
    if D == 1:
        shards = [run(0)]
    else:
        with ThreadPoolExecutor(D) as pool:
            shards = list(pool.map(run, range(D)))
    parts = [jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs), *s) if len(s) > 1 else s[0] for s in shards]
    if D == 1:
        return jax.tree_util.tree_map(lambda x: x[:B], parts[0])
    # One array per leaf, split over a one-axis mesh of the devices along the batch.
    sharding = NamedSharding(Mesh(np.asarray(devices), ("batch",)), PartitionSpec("batch"))

    def assemble(*xs):
        return jax.make_array_from_single_device_arrays((n * D,) + xs[0].shape[1:], sharding, list(xs))

    whole = jax.tree_util.tree_map(assemble, *parts)
    return whole if n * D == B else jax.tree_util.tree_map(lambda x: x[:B], whole)


def _to_device(tree, device):
    """Every array leaf of `tree` on `device` (the problem's constants included)."""
    return jax.tree_util.tree_map(lambda x: jax.device_put(x, device) if eqx.is_array(x) else x, tree)


def _batch_core(problem, layout, params0, data, frame_mask, weights, rtol, atol, max_steps, static):
    def one(p, d, m, w, rt, at):
        args = Args(with_weights(problem, w), d, m, layout)
        return solve_unjitted(args, p, rt, at, max_steps, **static)

    mask_axis = None if frame_mask is None else 0
    return jax.vmap(one, in_axes=(0, 0, mask_axis, 0, 0, 0))(params0, data, frame_mask, weights, rtol, atol)


@eqx.filter_jit
def _batch_jit(problem, layout, params0, data, frame_mask, weights, rtol, atol, max_steps, **static):
    return _batch_core(problem, layout, params0, data, frame_mask, weights, rtol, atol, max_steps, static)
