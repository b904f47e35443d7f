"""On-device profiling: decision latency, learner update cost and hardware traces.

`pimbot profile` runs the batch-size-1 decision loop with LIO's policy and
incentive heads (benign, or with ADMO on agent 0), samples CPU/GPU/thermal/
power sensors in a background thread and writes a run directory
(docs/profiling.md).
"""

from pimbot.profiling.decision_loop import CONTROLLERS, ProfileConfig
from pimbot.profiling.runner import profile, profile_one
from pimbot.profiling.tegrastats import parse_line as parse_tegrastats_line

__all__ = ["CONTROLLERS", "ProfileConfig", "parse_tegrastats_line", "profile", "profile_one"]
