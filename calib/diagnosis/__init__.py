"""Simulation against reality: where a recording departs from the nominal model, which physical
effect explains it, and how much the fit improves once that effect is modelled.

``diagnose(rec)`` fits the nominal model g = K m + b, simulates the same recording many times from
the fit (parametric bootstrap), compares residual features, tests each catalogued effect against
that null, fits the effects the recording shows and reports them (``Diagnosis.to_dict()``).
See docs/diagnosis.md for the method.
"""

from calib.diagnosis.run import EFFECT_NAMES, Diagnosis, diagnose

__all__ = ["EFFECT_NAMES", "Diagnosis", "diagnose"]
