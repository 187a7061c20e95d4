"""The paper's studies in simulation: its Monte Carlo study and its comparison of methods."""
