"""The top of the pipeline: the experiment, its report and the quick start."""
