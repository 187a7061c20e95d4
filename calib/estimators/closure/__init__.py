"""The closure estimator: its model, the weighted fit, one recording and many at once."""
