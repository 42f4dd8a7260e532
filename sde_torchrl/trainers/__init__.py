"""The training loop and what it calls each update: settings, optimiser and learning-rate schedule,
non-finite guard, the loop's record and summary, log lines and progress, signal handling."""
