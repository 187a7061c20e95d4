"""CPU-heavy work in worker processes: the estimators and CSV archives (compute), the model checks with their
queue, time limit and memory cap (diagnosis)."""
