"""Physical effects the protocol simulator can switch on, and the pipeline stages they act on.

The simulator (``calib.simulator``) produces a recording in three stages; an ``Effect`` may act on
any of them by overriding the matching hook (the default hooks change nothing):

1. ``on_trajectory(traj, rng) -> Trajectory`` — the true motion and time base, before the sensor:
   placement error (the pose after a turn), clock error (true sample times ``t`` differ from the
   stamps ``t_device`` the device reports).
2. ``on_sensor(m, ctx, rng) -> m`` — the sensor model from true rate to reading. ``m`` enters as the
   ideal reading (g - b) / k of eq. (1), before white noise; ``ctx`` gives the true rate, the specific
   force, the true times and the parameters. Misalignment, g-sensitivity, scale asymmetry and
   nonlinearity, bias drift and bias instability belong here.
3. ``on_output(out, rng) -> SensorOutput`` — what leaves the device, after white noise: saturation,
   quantisation, lost samples (drop rows with ``SensorOutput.keep``; ``seq`` then shows the gaps),
   the temperature channel.

Within a stage, effects run in the order given. Each effect draws from its own random generator,
so switching one effect on does not change the motion, the noise or another effect's draws.
``to_dict()`` (the dataclass fields plus ``name``) is what ``Truth.to_dict()["effects"]`` lists.

The catalogue (``CATALOGUE``), each model written as the true rate g (deg/s, sensor axes) in terms of
the reading m (deg/s), exactly as the simulator generates it (before white noise). Notation:
K = diag(k), b in deg/s of true rate, g0 = K m + b (the rate the paper's model eq. (1) gives),
a = specific force (g, sensor axes; +1 along the upward axis at rest), t = time since the first
sample (s), products and |.| element-wise per axis:

- bias_drift          g = K m + b + d t                        [+ c (T(t) - T0) with a temperature channel]
- axis_misalignment   g = (diag(k) + U) m + b,  U upper-triangular (K_xy, K_xz, K_yz)
- g_sensitivity       g = K (m - G a) + b,      G (3, 3) in (deg/s)/g
- scale_asymmetry     g = (1 + s sign(g0)) g0
- scale_nonlinearity  g = (1 + n |g0| / r0) g0,  r0 = 1000 deg/s
- saturation          m_out = clip(m, -FS, FS) (after optional quantisation)
- sample_loss         rows missing; t and seq of the kept rows unchanged, so both show the gap
- placement_error     the pose after turn j is off by the world-frame rotation Exp(e_j)
- clock_error         t_device = (1 + e) t_true
- bias_instability    g = K m + b + x(t),  x first-order Gauss-Markov (sigma, tau)

Each class docstring gives the exact equation, parameters, units and the CLI value syntax. The
equations hold exactly for one sensor-stage effect at a time; several compose in the order given
(each transforms the readings the previous one produced).

Adding an effect: subclass ``Effect`` as a frozen dataclass with a ``name`` and a ``usage``, override
the hooks it needs, decorate it with ``@register_effect`` so that ``parse_effect`` (the CLI's ``--effect
NAME=VALUE``) knows it, and give it ``from_text`` if its CLI value is not just its numeric fields. To
put it in the catalogue, give it a ``spec`` (``EffectSpec``: its equation, drawn range, typical size,
the motion that reveals it) and a ``draw``: the concealed-effect generator, the diagnosis's advice and
test sizes, the CLI help and the documentation's tables (``scripts/effects_tables.py``) all read them.
For the diagnosis to fit it, its rate-model term goes into ``calib.diagnosis.models.Model.rate`` (the
terms compose in one vectorised Jacobian) under the names of ``spec.model_params``.

Units: rates deg/s, times s, specific force g, angles deg, temperature degC."""

from calib.effects.axes import AxisMisalignment, GSensitivity
from calib.effects.base import (
    EFFECTS,
    Effect,
    SensorContext,
    SensorOutput,
    SimulationConfigError,
    Trajectory,
    catalogue,
    catalogue_specs,
    check_effects,
    effect_from_dict,
    parse_effect,
    register_effect,
)
from calib.effects.drift import TAU_RANGE_S, TEMP_RESOLUTION_C, BiasDrift, BiasInstability, TemperatureRamp, warmup_temperature
from calib.effects.impacts import Impacts
from calib.effects.noise import MotionNoise
from calib.effects.placement import PlacementError
from calib.effects.scale import STANDARD_FULL_SCALES_DPS, Saturation, ScaleAsymmetry, ScaleNonlinearity
from calib.effects.spec import DrawContext, EffectSpec, MagnitudeRange
from calib.effects.timing import LOSS_BURST, ClockError, SampleLoss

# The effects of the simulation-vs-reality catalogue (each with an ``EffectSpec``), in the documentation's order.
CATALOGUE: tuple[str, ...] = catalogue()
