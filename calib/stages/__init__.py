"""Stages: the Stage type, the streaming detector that splits a recording into stills, full turns and other motions
(config, prefix_sums, detector), the protocol finder that picks the still and the three turns out of them (protocol),
the reasons a protocol is not found (hints), the stages resolved once for every estimator (resolve), which protocol a
recording holds (recognise) and a hand turn's physics as it is recorded (turn_checks)."""
