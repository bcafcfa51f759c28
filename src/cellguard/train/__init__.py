"""Training small policies for demos and tests (the demo policy); above the runner, which it drives."""
