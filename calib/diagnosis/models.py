"""Estimator-side models of the catalogued effects: the true rate as a function of the reading.

The same equations as the simulator (``calib.effects``), with g0 = K m + b the nominal model:

- bias_drift          g = K m + b + d t                     (d in deg/s per s, t since the first sample)
  (bias_drift_temp)   g = K m + b + c (T - T0)               (with a temperature channel: c in deg/s per degC;
                                                               T0 absorbed by b)
- axis_misalignment   g = (K + U) m + b                       (U upper off-diagonal: U_xy, U_xz, U_yz)
- g_sensitivity       g = K (m - G a) + b                     (G 3x3 in (deg/s)/g, a the specific force in g)
- scale_asymmetry     g = (1 + s sign(g0)) g0                 (s per axis)
- scale_nonlinearity  g = (1 + n |g0| / r0) g0                (n per axis, r0 = 1000 deg/s)
- saturation          m = clip(m_true): a clipped turn's closure is unknown (a free rotation delta_j per clipped
                      turn); ``plateau`` instead rebuilds each clipped plateau as m + h c(t), c a parabolic cap
- placement_error     turn j ends rotated by rho_j from where it began: closure r_j = rho_j
- bias_instability    g = K m + b + x(t), x a first-order Gauss-Markov process (variance model, variance.py)
- sample_loss, clock_error: the time base (timebase.py)

``Model`` stacks the parameters psi = (k, b, <effect parameters>) and evaluates the calibrated rate
and its Jacobian with respect to psi at turn samples or still blocks, vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from calib.diagnosis.data import Inputs
from calib.effects import catalogue_specs

R0_DPS = 1000.0  # reference rate of the nonlinearity, deg/s

# Effects that change the rate model, with their parameter counts (saturation and placement vary).
RATE_EFFECTS = ("axis_misalignment", "bias_drift", "bias_drift_temp", "g_sensitivity", "scale_asymmetry",
                "scale_nonlinearity", "plateau")
# Names of each fixed-size rate term's parameters, from the catalogue (EffectSpec.model_params).
_PARAM_NAMES: dict[str, tuple[str, ...]] = {term: names for spec in catalogue_specs().values() for term, names in spec.model_params.items()}
_FIXED_SIZE = {term: len(names) for term, names in _PARAM_NAMES.items()}


@dataclass(frozen=True)
class Model:
    """The nominal model plus a set of effects. ``J`` turns; ``cap_axis`` the axis of each clipped plateau;
    ``clipped`` the turns that hold clipped readings."""

    effects: tuple[str, ...] = ()
    J: int = 0
    cap_axis: tuple[int, ...] = ()
    clipped: tuple[int, ...] = ()
    clip_basis: tuple[np.ndarray, ...] = field(default=(), compare=False)  # (3, q) free closure directions per clipped turn
    slices: dict[str, slice] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        pos = 6
        sl: dict[str, slice] = {"k": slice(0, 3), "b": slice(3, 6)}
        for name in sorted(set(self.effects), key=_order):
            size = self._size(name)
            if size == 0:
                continue
            sl[name] = slice(pos, pos + size)
            pos += size
        object.__setattr__(self, "slices", sl)

    def _size(self, name: str) -> int:
        if name in _FIXED_SIZE:
            return _FIXED_SIZE[name]
        if name == "plateau":
            return len(self.cap_axis)
        if name == "saturation":
            return sum(self._clip_basis(c).shape[1] for c in range(len(self.clipped)))
        if name == "placement_error":
            return 3 * self.J
        return 0  # variance and time-base effects have no rate parameters

    def with_effects(self, *names: str) -> Model:
        return replace(self, effects=tuple(sorted(set(self.effects) | set(names), key=_order)))

    def without(self, *names: str) -> Model:
        return replace(self, effects=tuple(e for e in self.effects if e not in names))

    def _clip_basis(self, c: int) -> np.ndarray:
        return self.clip_basis[c] if c < len(self.clip_basis) else np.eye(3)

    @property
    def P(self) -> int:
        return max(s.stop for s in self.slices.values())

    @property
    def rate_params(self) -> np.ndarray:
        """Indices of the parameters that enter the rate (all but the closure offsets of placement and clipping)."""
        idx = np.arange(self.P)
        for name in ("placement_error", "saturation"):
            if name in self.slices:
                s = self.slices[name]
                idx = idx[(idx < s.start) | (idx >= s.stop)]
        return idx

    def closure_offsets(self) -> list[tuple[int, int, np.ndarray]]:
        """(turn, first parameter index, basis (3, q)) of every free closure offset: placement rotations
        (3 per turn) and clipped turns (3, or the 2 off-axis directions when no other turn fixes that axis)."""
        out = []
        if "placement_error" in self.slices:
            s = self.slices["placement_error"].start
            out += [(j, s + 3 * j, np.eye(3)) for j in range(self.J)]
        if "saturation" in self.slices:
            s = self.slices["saturation"].start
            for c, j in enumerate(self.clipped):
                B = self._clip_basis(c)
                out.append((j, s, B))
                s += B.shape[1]
        return out

    def names(self) -> list[str]:
        out = ["k_x", "k_y", "k_z", "b_x", "b_y", "b_z"]
        for name, s in self.slices.items():
            if name in ("k", "b"):
                continue
            if name == "plateau":
                out += [f"h_{i}" for i in range(s.stop - s.start)]
            elif name == "saturation":
                out += [f"delta_{j}_{q}" for c, j in enumerate(self.clipped) for q in range(self._clip_basis(c).shape[1])]
            elif name == "placement_error":
                out += [f"rho_{j}_{a}" for j in range(self.J) for a in "xyz"]
            else:
                out += list(_PARAM_NAMES[name])
        return out

    def zeros(self, base: np.ndarray, base_model: Model | None = None) -> np.ndarray:
        """Parameters (R, P) of this model from those of ``base_model`` (nominal if None), new ones 0."""
        base = np.atleast_2d(base)
        out = np.zeros((base.shape[0], self.P))
        src = base_model or replace(self, effects=())
        for name, s in src.slices.items():
            if name in self.slices:
                out[:, self.slices[name]] = base[:, s]
        return out

    # ------------------------------------------------------------------ the rate

    def rate(self, psi: np.ndarray, inp: Inputs, jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Calibrated rate w (..., 3) and dw/dpsi (..., 3, Pr) over the rate parameters, at ``inp``.

        ``psi`` (..., P) broadcasts against the inputs' leading shape.
        """
        sl = self.slices
        m = inp.m
        lead = np.broadcast_shapes(m.shape[:-1], psi.shape[:-1])
        ridx = self.rate_params
        col = {int(p): i for i, p in enumerate(ridx)}
        k = psi[..., 0:3]
        # (param index, axis, d m_axis / d param (...)): each of these parameters moves one axis of the corrected reading
        dm: list[tuple[int, int, np.ndarray]] = []
        if "plateau" in sl and inp.cap is not None:
            s = sl["plateau"]
            h = psi[..., s]
            m = m.copy() if m.shape == lead + (3,) else np.broadcast_to(m, lead + (3,)).copy()
            for c, ax in enumerate(self.cap_axis):
                m[..., ax] += h[..., c] * inp.cap[..., c]
                dm.append((s.start + c, ax, inp.cap[..., c]))
        if "g_sensitivity" in sl:
            if inp.a is None:
                raise ValueError("g_sensitivity needs the specific force")
            G = psi[..., sl["g_sensitivity"]].reshape(psi.shape[:-1] + (3, 3))
            a = inp.a
            m = m - (G[..., 0] * a[..., 0, None] + G[..., 1] * a[..., 1, None] + G[..., 2] * a[..., 2, None])
            if jacobian:
                base = sl["g_sensitivity"].start
                dm.extend((base + 3 * i + j, i, -a[..., j]) for i in range(3) for j in range(3))
        g0 = k * m + psi[..., 3:6]
        U = None
        if "axis_misalignment" in sl:
            U = psi[..., sl["axis_misalignment"]]
            g0 = g0.copy()
            g0[..., 0] += U[..., 0] * m[..., 1] + U[..., 1] * m[..., 2]
            g0[..., 1] += U[..., 2] * m[..., 2]
        if "bias_drift" in sl:
            g0 = g0 + psi[..., sl["bias_drift"]] * inp.t[..., None]
        if "bias_drift_temp" in sl:
            if inp.temp is None:
                raise ValueError("temperature drift needs the temperature channel")
            g0 = g0 + psi[..., sl["bias_drift_temp"]] * inp.temp[..., None]
        dg0 = None
        if jacobian:
            dg0 = np.zeros(lead + (3, ridx.size))
            for i in range(3):
                dg0[..., i, col[i]] = m[..., i]
                dg0[..., i, col[3 + i]] = 1.0
            if U is not None:
                s = sl["axis_misalignment"].start
                dg0[..., 0, col[s]] = m[..., 1]
                dg0[..., 0, col[s + 1]] = m[..., 2]
                dg0[..., 1, col[s + 2]] = m[..., 2]
            for name, x in (("bias_drift", inp.t), ("bias_drift_temp", inp.temp)):
                if name in sl:
                    s = sl[name].start
                    for i in range(3):
                        dg0[..., i, col[s + i]] = x
            for p, ax, d in dm:  # d g0 / d p = (K + U) d m / d p, with d m / d p on one axis
                dg0[..., ax, col[p]] = k[..., ax] * d
                if U is not None and ax == 1:
                    dg0[..., 0, col[p]] = U[..., 0] * d
                elif U is not None and ax == 2:
                    dg0[..., 0, col[p]] = U[..., 1] * d
                    dg0[..., 1, col[p]] = U[..., 2] * d
        if inp.offset is not None:
            g0 = g0 + inp.offset
            if jacobian and inp.doffset is not None:
                assert dg0 is not None
                dg0 += inp.doffset  # dg0 is this call's own array
        g = g0
        if "scale_asymmetry" in sl or "scale_nonlinearity" in sl:
            f = np.ones(lead + (3,))
            a0 = np.abs(g0)
            if "scale_asymmetry" in sl:
                sv = psi[..., sl["scale_asymmetry"]]
                f = f * (1.0 + sv * np.sign(g0))
            if "scale_nonlinearity" in sl:
                s = sl["scale_nonlinearity"]
                nv = psi[..., s]
                fn = 1.0 + nv * a0 / R0_DPS
                f = f * fn
            g = g0 * f
            if jacobian:
                assert dg0 is not None
                # g = g0 f(g0): dg/dg0 = f + g0 f'(g0); both factors are products of per-axis terms
                fa = 1.0 + psi[..., sl["scale_asymmetry"]] * np.sign(g0) if "scale_asymmetry" in sl else np.ones(np.shape(g0))
                nterm = psi[..., sl["scale_nonlinearity"]] * a0 / R0_DPS if "scale_nonlinearity" in sl else np.zeros(np.shape(g0))
                fn = 1.0 + nterm
                dfac = fa * (fn + nterm)  # d g / d g0, per axis
                dg = dg0  # made by this call: scaled in place
                dg *= dfac[..., None]
                if "scale_asymmetry" in sl:
                    s = sl["scale_asymmetry"].start
                    for i in range(3):
                        dg[..., i, col[s + i]] = a0[..., i] * fn[..., i]
                if "scale_nonlinearity" in sl:
                    s = sl["scale_nonlinearity"].start
                    for i in range(3):
                        dg[..., i, col[s + i]] = g0[..., i] * a0[..., i] / R0_DPS * fa[..., i]
                dg0 = dg
        return g, dg0


_ORDER = ("axis_misalignment", "bias_drift", "bias_drift_temp", "g_sensitivity", "scale_asymmetry", "scale_nonlinearity",
          "plateau", "saturation", "placement_error")


def _order(name: str) -> int:
    return _ORDER.index(name) if name in _ORDER else len(_ORDER)
