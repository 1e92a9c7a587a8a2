"""Development tools: sample generator, fuzz harness, hostile-capture runner. Not part of the wheel."""
