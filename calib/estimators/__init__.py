"""Estimators: each turns a recording's stages into a CalibrationResult; `registry` names them."""
