"""Learned parts that serve the optimisers (Huang ch. 6-7), in equinox + optax.

- `jaxmocap.learned.dip`: the Deep Inertial Poser, a bidirectional LSTM from 6 IMUs to
  SMPL joint rotations (eq. 6.1-6.8), used to start SIP (`sparse_inertial_poser(...,
  init="birnn")`).
- `jaxmocap.learned.activity`: activity recognition from one wrist IMU: an MLP over 6 s
  windows plus a linear-chain CRF (ch. 7).

Submodules load on first use (they import optax).
"""
