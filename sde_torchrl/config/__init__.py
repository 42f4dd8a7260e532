"""The config layer: Hydra schemas and their checks, building a trainer from a checked config, and
composing the repository's config from Python."""
