"""Training: run configs, the compiled training loop, run directories, summaries,
trackers and progress."""
