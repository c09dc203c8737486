"""Command-line interface (`forestslam ...`). Commands import their heavy modules lazily."""
