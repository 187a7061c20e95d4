"""Stage detection: the streaming detector that splits a recording into stills, full turns and other motions
(config, segments, detector), and the protocol finder that picks the still and the three turns out of them
(protocol), the reasons a protocol is not found (hints), and the stages resolved once for every estimator
(resolve)."""

from .config import LiveState, StageConfig, StageConfigError, StageEvent, clip_run_needed
from .detector import StageTracker, detect_stages
from .hints import find_protocol_in
from .protocol import ProtocolStages, find_protocol
from .resolve import ResolvedStages, resolve_stages
