"""Deep Inertial Poser (Huang ch. 6): a bidirectional LSTM from 6 IMUs to SMPL joint rotations.

Inputs (§6.3.2-6.3.4). From calibrated readings (`InertialSetup`: measured R_s^g, global
free accelerations a^g, sensor-to-bone rotations R_s^b from the known first pose):

    virtual bone orientations  R_b^g(t) = R_s^g(t) (R_s^b)ᵀ              (eq. 6.5-6.6)
    root-relative               R̄_s = R_root⁻¹ R_s,  ā_s = R_root⁻¹ (a_s - a_root)  (eq. 6.7-6.8)
    x_t = [vec(R̄_1 .. R̄_5), ā_1 .. ā_5] ∈ R⁶⁰                                (§6.3.4)

with the pelvis sensor as root (index 5 of the "sip6" set). Dropped samples (NaN) hold
the last reported value (the first one before any report); a sensor that never reports
reads 0, what input dropout trains the network to expect. Inputs are standardised by the
training set's mean and standard deviation (stored with the weights).

Network (§6.2.4, §6.3.1, Fig. 6.4): input dropout (keep 0.8) → dense layer (ReLU; the
thesis does not name its activation) → two bidirectional LSTM layers, the second reading
both directions of the first → per frame the mean μ_t and standard deviation σ_t
(softplus) of the 15 "major" SMPL joints' local rotation matrices (135 values, DIP's
SMPL_MAJOR_JOINTS) and, as the auxiliary task, of the 15 normalised input accelerations
(eq. 6.3). Loss: the Gaussian negative log-likelihood of both (eq. 6.2-6.3), over real
(unpadded) frames. Our choices: LSTM forget-gate bias 1 (TensorFlow's default), σ ≥ 1e-3.

Poses out (`birnn_poses`): μ per joint projected onto SO(3) (`rotation.nearest_rotation`),
the root from the pelvis sensor's virtual bone orientation, the joints DIP does not
predict (wrists, hands, ankles, feet) at rest: a start for SIP, which then fits all.

The default model (`default_dip_model`) ships in `dip_model.npz` beside this file; its
README says what data, which commit and how long it was trained, and what it has seen
(so what it must never be evaluated on).
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..geometry.imu_calibration import normalize_to_root, virtual_bone_orientations
from ..rotation import axis_angle_to_matrix, matrix_to_axis_angle, nearest_rotation
from ._weights import fill_module, read_header, save_module

__all__ = [
    "MAJOR_JOINTS",
    "ROOT_SENSOR",
    "SIP6_BONES",
    "DIPConfig",
    "DIPNetwork",
    "DIPModelError",
    "dip_inputs",
    "dip_targets",
    "dip_loss",
    "birnn_poses",
    "network_poses",
    "save_dip_model",
    "load_dip_model",
    "default_dip_model",
    "DEFAULT_MODEL_PATH",
]

#: DIP's SMPL_MAJOR_JOINTS: hips, spine 1-3, knees, neck, collars, head, shoulders, elbows.
MAJOR_JOINTS = (1, 2, 3, 4, 5, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19)
#: The bones of the "sip6" set (left/right forearm, left/right lower leg, head, pelvis).
SIP6_BONES = (18, 19, 4, 5, 15, 0)
ROOT_SENSOR = 5
NUM_INPUTS = 12 * (len(SIP6_BONES) - 1)
NUM_POSE = 9 * len(MAJOR_JOINTS)
NUM_ACC = 3 * (len(SIP6_BONES) - 1)
MIN_SIGMA = 1e-3
FORMAT = "jaxmocap_dip_model"
FORMAT_VERSION = 1
DEFAULT_MODEL_PATH = Path(__file__).with_name("dip_model.npz")


class DIPModelError(ValueError):
    """A DIP weights file that cannot be read or does not match the network it claims."""


def hold_dropped(x: Array) -> Array:
    """(T, S, ...) with NaN samples replaced by the last reported one (the first before any)."""
    ok = jnp.all(jnp.isfinite(x), axis=tuple(range(2, x.ndim)))  # (T, S)

    def fill(carry, xs):
        value, seen = carry
        xt, okt = xs
        okb = okt.reshape(okt.shape + (1,) * (xt.ndim - 1))
        value = jnp.where(okb, xt, value)
        return (value, seen | okt), value

    def run(seq, oks):
        init = (jnp.zeros_like(seq[0]), jnp.zeros(oks.shape[1:], bool))
        return jax.lax.scan(fill, init, (seq, oks))[1]

    forward = run(x, ok)
    backward = run(x[::-1], ok[::-1])[::-1]
    seen = jnp.cumsum(ok, axis=0) > 0
    seen = seen.reshape(seen.shape + (1,) * (x.ndim - 2))
    return jnp.where(seen, forward, backward)


def dip_inputs(orientation: Array, acceleration: Array, sensor_to_bone: Array) -> Array:
    """The 60 raw network inputs per frame (eq. 6.6-6.8, §6.3.4).

    Args:
        orientation: (T, 6, 3, 3) measured R_s^g in the model frame ("sip6" order); NaN = dropped.
        acceleration: (T, 6, 3) global free accelerations a^g (m/s², gravity removed).
        sensor_to_bone: (6, 3, 3) R_s^b from calibration.
    Returns:
        (T, 60): vec(R̄_1..R̄_5) then ā_1..ā_5 (unstandardised).
    """
    orientation, acceleration = jnp.asarray(orientation), jnp.asarray(acceleration)
    T = orientation.shape[0]
    if orientation.shape != (T, 6, 3, 3) or acceleration.shape != (T, 6, 3) or jnp.shape(sensor_to_bone) != (6, 3, 3):
        raise ValueError(
            f"DIP reads the 6 'sip6' sensors: orientation (T, 6, 3, 3), acceleration (T, 6, 3), "
            f"sensor_to_bone (6, 3, 3); got {orientation.shape}, {acceleration.shape}, {jnp.shape(sensor_to_bone)}."
        )
    return _inputs(_virtual_bones(orientation, jnp.asarray(sensor_to_bone, orientation.dtype)), acceleration)


def _virtual_bones(orientation: Array, sensor_to_bone: Array) -> Array:
    """Eq. 6.6 with dropped samples held: (T, 6, 3, 3) virtual bone orientations."""
    return virtual_bone_orientations(hold_dropped(orientation), sensor_to_bone)


def _inputs(bones: Array, acceleration: Array) -> Array:
    """Eq. 6.7-6.8 and §6.3.4 from virtual bone orientations: (T, 60)."""
    T = bones.shape[0]
    R_bar, a_bar = normalize_to_root(bones, hold_dropped(acceleration), ROOT_SENSOR)
    others = np.array([s for s in range(6) if s != ROOT_SENSOR])
    return jnp.concatenate([R_bar[:, others].reshape(T, -1), a_bar[:, others].reshape(T, -1)], -1)


def dip_targets(poses: Array) -> Array:
    """(T, 24, 3) axis-angle poses -> (T, 135) local rotation matrices of `MAJOR_JOINTS`."""
    poses = jnp.asarray(poses)
    return axis_angle_to_matrix(poses[:, np.asarray(MAJOR_JOINTS)]).reshape(poses.shape[0], -1)


class LSTM(eqx.Module):
    """One LSTM direction; the input projection of all frames is one matmul outside the scan."""

    weight_ih: Array
    weight_hh: Array
    bias: Array
    reverse: bool = eqx.field(static=True)

    def __init__(self, num_in: int, hidden: int, reverse: bool, key):
        k1, k2 = jax.random.split(key)
        bound = 1.0 / np.sqrt(hidden)
        self.weight_ih = jax.random.uniform(k1, (4 * hidden, num_in), minval=-bound, maxval=bound)
        self.weight_hh = jax.random.uniform(k2, (4 * hidden, hidden), minval=-bound, maxval=bound)
        self.bias = jnp.zeros(4 * hidden).at[hidden : 2 * hidden].set(1.0)  # forget gate: TF's forget_bias
        self.reverse = reverse

    def __call__(self, x: Array, mask: Array) -> Array:
        """(T, num_in), (T,) real-frame mask -> (T, hidden); padded frames keep the state at 0."""
        hidden = self.weight_hh.shape[1]
        gates_in = x @ self.weight_ih.T + self.bias

        def step(carry, xs):
            h, c = carry
            g, m = xs
            i, f, z, o = jnp.split(g + self.weight_hh @ h, 4)
            c_new = jax.nn.sigmoid(f) * c + jax.nn.sigmoid(i) * jnp.tanh(z)
            h_new = jax.nn.sigmoid(o) * jnp.tanh(c_new)
            h, c = jnp.where(m, h_new, 0.0), jnp.where(m, c_new, 0.0)
            return (h, c), h

        zero = jnp.zeros(hidden, x.dtype)
        _, out = jax.lax.scan(step, (zero, zero), (gates_in, mask), reverse=self.reverse)
        return out


@dataclasses.dataclass(frozen=True)
class DIPConfig:
    """Network size and regularisation (defaults: the thesis's, §6.3.1 and Fig. 6.4)."""

    hidden: int = 512
    input_keep: float = 0.8

    def __post_init__(self):
        if not isinstance(self.hidden, (int, np.integer)) or self.hidden < 1:
            raise ValueError(f"DIPConfig.hidden must be an int >= 1, got {self.hidden!r}.")
        if not 0.0 < self.input_keep <= 1.0:
            raise ValueError(f"DIPConfig.input_keep must be in (0, 1], got {self.input_keep!r}.")


class DIPNetwork(eqx.Module):
    """The BiRNN of Fig. 6.4 with its input standardisation; one sequence (T, 60) per call."""

    input_mean: Array
    input_std: Array
    dense: eqx.nn.Linear
    layers: tuple[tuple[LSTM, LSTM], ...]
    pose_head: eqx.nn.Linear  # μ and σ of the 135 pose values
    acc_head: eqx.nn.Linear  # μ and σ of the 15 accelerations (auxiliary task, eq. 6.3)
    config: DIPConfig = eqx.field(static=True)

    def __init__(self, config: DIPConfig = DIPConfig(), key=None, input_mean=None, input_std=None):
        key = jax.random.PRNGKey(0) if key is None else key
        ks = jax.random.split(key, 7)
        h = config.hidden
        self.config = config
        self.input_mean = jnp.zeros(NUM_INPUTS) if input_mean is None else jnp.asarray(input_mean, jnp.float32)
        self.input_std = jnp.ones(NUM_INPUTS) if input_std is None else jnp.asarray(input_std, jnp.float32)
        self.dense = eqx.nn.Linear(NUM_INPUTS, h, key=ks[0])
        self.layers = (
            (LSTM(h, h, False, ks[1]), LSTM(h, h, True, ks[2])),
            (LSTM(2 * h, h, False, ks[3]), LSTM(2 * h, h, True, ks[4])),
        )
        self.pose_head = eqx.nn.Linear(2 * h, 2 * NUM_POSE, key=ks[5])
        self.acc_head = eqx.nn.Linear(2 * h, 2 * NUM_ACC, key=ks[6])

    def __call__(self, x: Array, mask: Array | None = None, key=None) -> tuple[Array, Array, Array, Array]:
        """(T, 60) raw inputs -> pose μ, σ (T, 135) and acceleration μ, σ (T, 15).

        `key` switches input dropout on (training); `mask` (T,) marks real frames.
        """
        mask = jnp.ones(x.shape[0], bool) if mask is None else mask
        x = (x - jax.lax.stop_gradient(self.input_mean)) / jax.lax.stop_gradient(self.input_std)
        if key is not None and self.config.input_keep < 1.0:
            keep = jax.random.bernoulli(key, self.config.input_keep, x.shape)
            x = jnp.where(keep, x / self.config.input_keep, 0.0)
        h = jax.nn.relu(x @ self.dense.weight.T + self.dense.bias)
        for fwd, bwd in self.layers:
            h = jnp.concatenate([fwd(h, mask), bwd(h, mask)], -1)
        pose = h @ self.pose_head.weight.T + self.pose_head.bias
        acc = h @ self.acc_head.weight.T + self.acc_head.bias
        sigma = lambda s: jax.nn.softplus(s) + MIN_SIGMA  # noqa: E731
        return pose[:, :NUM_POSE], sigma(pose[:, NUM_POSE:]), acc[:, :NUM_ACC], sigma(acc[:, NUM_ACC:])


def _gaussian_nll(mu, sigma, y, mask):
    """Mean over real frames and dimensions of -log N(y | μ, σ²) without the constant (eq. 6.2)."""
    nll = jnp.log(sigma) + 0.5 * jnp.square((y - mu) / sigma)
    m = mask[..., None].astype(nll.dtype)
    return jnp.sum(nll * m) / jnp.maximum(jnp.sum(m) * nll.shape[-1], 1.0)


def dip_loss(network: DIPNetwork, inputs, targets, mask, key=None, acc_weight: float = 1.0):
    """Eq. 6.2 + eq. 6.3 for a batch: inputs (B, T, 60), targets (B, T, 135), mask (B, T).

    The auxiliary target is the normalised acceleration part of the inputs (before dropout).
    Returns (loss, (pose NLL, acceleration NLL)).
    """
    if key is None:
        mu, sigma, acc_mu, acc_sigma = jax.vmap(lambda x, m: network(x, m))(inputs, mask)
    else:
        keys = jax.random.split(key, inputs.shape[0])
        mu, sigma, acc_mu, acc_sigma = jax.vmap(lambda x, m, k: network(x, m, k))(inputs, mask, keys)
    acc = slice(NUM_INPUTS - NUM_ACC, NUM_INPUTS)
    acc_true = (inputs[..., acc] - network.input_mean[acc]) / network.input_std[acc]
    pose_nll = _gaussian_nll(mu, sigma, targets, mask)
    acc_nll = _gaussian_nll(acc_mu, acc_sigma, acc_true, mask)
    return pose_nll + acc_weight * acc_nll, (pose_nll, acc_nll)


@eqx.filter_jit
def network_poses(network: DIPNetwork, inputs: Array, root: Array, mask: Array | None = None) -> Array:
    """(T, 24, 3) axis-angle poses from raw inputs (T, 60) and root orientations (T, 3, 3);
    `mask` (T,) marks real frames of a padded sequence."""
    mu = network(inputs, mask)[0].reshape(-1, len(MAJOR_JOINTS), 3, 3)
    local = matrix_to_axis_angle(nearest_rotation(mu))
    poses = jnp.zeros((inputs.shape[0], 24, 3), local.dtype)
    poses = poses.at[:, np.asarray(MAJOR_JOINTS)].set(local)
    return poses.at[:, 0].set(matrix_to_axis_angle(root).astype(local.dtype))


def birnn_poses(setup, network: DIPNetwork | None = None) -> Array:
    """The DIP poses (T, 24, 3) of a calibrated 6-IMU sequence: a start for SIP.

    Args:
        setup: an `InertialSetup` on the "sip6" sensors, in that order
            (`app.scenarios.inertial_setup`, `calibrate`, `from_dip(..., sensors=[7, 8, 11, 12, 0, 2])`).
        network: a trained `DIPNetwork` (default: `default_dip_model()`).
    """
    if tuple(setup.bones) != SIP6_BONES:
        raise ValueError(
            f"the DIP network reads the 'sip6' sensors on bones {SIP6_BONES} (left/right forearm, "
            f"left/right lower leg, head, pelvis), got bones {tuple(setup.bones)}; calibrate those six, "
            "in that order (for DIP-IMU's 17 sensors: sensors=[7, 8, 11, 12, 0, 2])."
        )
    network = default_dip_model() if network is None else network
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    d = setup.data
    bones = _virtual_bones(f32(d.orientation), f32(d.sensor_to_bone))
    x, root = _inputs(bones, f32(d.acceleration)), bones[:, ROOT_SENSOR]
    # Padded to a multiple of 128 frames (masked: padding reaches neither direction), so
    # sequences of many lengths share a few compilations.
    T = x.shape[0]
    pad = -T % 128
    mask = jnp.arange(T + pad) < T
    x, root = (jnp.concatenate([a, jnp.repeat(a[-1:], pad, 0)]) for a in (x, root))
    return network_poses(network, x, root, mask)[:T].astype(setup.pose0.dtype)


# --- weights files -----------------------------------------------------------------


def save_dip_model(path, network: DIPNetwork, meta: dict | None = None, dtype=np.float16) -> Path:
    """Write the weights (as `dtype`, float16 by default: half the size, error far below the
    network's own) with the configuration and `meta` (provenance) as JSON; atomic."""
    header = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "config": dataclasses.asdict(network.config),
        "meta": meta or {},
    }
    return save_module(path, network, header, dtype)


def load_dip_model(path) -> tuple[DIPNetwork, dict]:
    """(network, meta) from a file of `save_dip_model`; `DIPModelError` names what does not match."""
    header, arrays = read_header(path, FORMAT, FORMAT_VERSION, DIPModelError, "jaxmocap.learned.dip.save_dip_model")
    try:
        skeleton = DIPNetwork(DIPConfig(**header["config"]))
    except (KeyError, TypeError, ValueError) as e:
        raise DIPModelError(f"{path}: bad network configuration {header.get('config')!r} ({e}).") from None
    return fill_module(skeleton, header, arrays, path, DIPModelError), header.get("meta", {})


@functools.cache
def default_dip_model() -> DIPNetwork:
    """The shipped network (`dip_model.npz`; see the README beside it), loaded once."""
    return load_dip_model(DEFAULT_MODEL_PATH)[0]
