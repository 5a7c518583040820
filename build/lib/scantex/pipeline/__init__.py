"""The enhance pipeline: configuration and the orchestration that wires the stages together."""
