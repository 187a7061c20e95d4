"""A watch's report: the verdict on each parameter of the calibration in force, the evidence it rests on and what
was left out, and how the bias (and, where the evidence allows, k) followed the sensor's temperature."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from calib.watch.bias import BiasFindings
from calib.watch.evidence import Evidence
from calib.watch.scale import ScaleFindings
from calib.watch.verdict import ParameterVerdict


@dataclass(frozen=True)
class WatchReport:
    """Whether a calibration still holds, from a recording made with it in force."""

    duration_s: float
    rests: int
    rest_s: float
    reorientations: int
    left_out: int
    left_out_s: float
    temperature_c: tuple[float, float] | None  # the recording's coldest and warmest (degC)
    bias: BiasFindings
    scale: ScaleFindings
    warnings: list[str] = field(default_factory=list)

    @property
    def parameters(self) -> list[ParameterVerdict]:
        return [*self.scale.verdicts, *self.bias.verdicts]

    @property
    def verdict(self) -> str:
        """moved when any parameter moved, holds when every one holds, else cannot tell."""
        said = {p.verdict for p in self.parameters}
        return "moved" if "moved" in said else "holds" if said == {"holds"} else "cannot tell"

    @classmethod
    def of(cls, ev: Evidence, bias: BiasFindings, scale: ScaleFindings) -> WatchReport:
        rec = ev.rec
        temps = None
        if rec.temp is not None and ev.has_temperature:
            temps = (round(float(min(r.temperature_c for r in ev.rests if r.temperature_c is not None)), 2),
                     round(float(max(r.temperature_c for r in ev.rests if r.temperature_c is not None)), 2))
        rest_s = float(sum(rec.t[r.end - 1] - rec.t[r.start] for r in ev.rests))
        warnings = []
        if rec.duration_s > 0 and ev.left_out_s / rec.duration_s > 0.5:
            warnings.append(f"{100 * ev.left_out_s / rec.duration_s:.0f} % of the recording is motion too long to measure "
                            "(walking, restlessness): only its rests and the short re-orientations between them are used")
        if not ev.has_temperature and any(p.since is None and p.verdict in ("moved", "cannot tell") for p in bias.verdicts):
            warnings.append("the recording has no temperature column: a bias unlike the calibration's from its start may be "
                            "the sensor's temperature, not the sensor (0.01-0.05 (deg/s)/°C for this class of gyroscope); "
                            "record the temperature to tell them apart")
        return cls(rec.duration_s, len(ev.rests), rest_s, scale.used, ev.left_out, ev.left_out_s, temps, bias, scale, warnings)

    def to_json(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "parameters": [p.to_json() for p in self.parameters],
            "evidence": {"duration_s": round(self.duration_s, 2), "rests": self.rests, "rest_s": round(self.rest_s, 1),
                         "reorientations": self.reorientations,
                         "left_out": {"motions": self.left_out, "seconds": round(self.left_out_s, 1),
                                      "fraction": round(self.left_out_s / self.duration_s, 4) if self.duration_s else 0.0,
                                      "why": "motion between two rests longer than 10 s (walking, restlessness) cannot "
                                             "be integrated to the precision a calibration needs"}},
            "temperature_c": None if self.temperature_c is None else list(self.temperature_c),
            "bias": self.bias.to_json(),
            "scale": self.scale.to_json(),
            "warnings": list(self.warnings),
        }

    def lines(self) -> list[str]:
        """The report in words, a line each."""
        out = [f"verdict: {self.verdict}"]
        out += [f"  {p.sentence()}" for p in self.parameters]
        frac = 100 * self.left_out_s / self.duration_s if self.duration_s else 0.0
        out.append(f"evidence: {self.rests} rests ({self.rest_s:.0f} s), {self.reorientations} re-orientations; "
                   f"{self.left_out} longer motions left out ({self.left_out_s:.0f} s, {frac:.0f} % of the recording)")
        b = self.bias
        if b.temperature_coeff is not None and b.temperature_coeff_std is not None and self.temperature_c:
            tc = ", ".join(f"{v:+.4f} ± {s:.4f}" for v, s in zip(b.temperature_coeff, b.temperature_coeff_std, strict=True))
            out.append(f"bias against temperature ({self.temperature_c[0]:.1f}–{self.temperature_c[1]:.1f} °C): "
                       f"{tc} (deg/s)/°C (x, y, z), referred to {b.reference}")
        elif b.warmth_change is not None and b.warmth_change_std is not None:
            ch = ", ".join(f"{v:+.3f} ± {s:.3f}" for v, s in zip(b.warmth_change, b.warmth_change_std, strict=True))
            out.append(f"the bias moved with the wearer's warmth: by {ch} deg/s (x, y, z) from the first rest, "
                       f"time constant {b.warmth_tau_s:.0f} s; record the temperature channel to model it")
        sc = self.scale
        if sc.temperature_coeff is not None and sc.temperature_coeff_std is not None:
            tc = ", ".join(f"{1e4 * v:+.2f} ± {1e4 * s:.2f}" for v, s in zip(sc.temperature_coeff, sc.temperature_coeff_std, strict=True))
            out.append(f"scale factors against temperature: {tc} e-4 per °C (x, y, z)")
        out.append("re-orientations that exercised x, y, z: " + ", ".join(str(n) for n in sc.exercised))
        out += [f"warning: {w}" for w in self.warnings]
        return out
