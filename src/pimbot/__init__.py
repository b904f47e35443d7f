"""pimbot: stress-testing incentive-based multi-agent RL against manipulation."""

__version__ = "0.1.0"
