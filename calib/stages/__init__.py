"""Stage detection: the streaming detector that splits a recording into stills, full turns and other motions
(config, segments, detector), and the protocol finder that picks the still and the three turns out of them
(protocol)."""

from .config import LiveState, StageConfig, StageConfigError, StageEvent, clip_run_needed
from .detector import StageTracker, detect_stages
from .protocol import ProtocolStages, find_protocol
