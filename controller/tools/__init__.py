"""Tools beside the runtime: bench, experiments, fault scenarios, analysis and plots (matplotlib)."""
