"""The ground floor: argument checks, broadcasting helpers, per-run random streams, atomic files and
95 % intervals. Imports nothing else of the package."""
