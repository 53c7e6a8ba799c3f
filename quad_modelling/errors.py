"""Exceptions of quad_modelling.

Every exception carries a one-line message that names the file, topic, field or
row at fault, so the CLI can print it as is and exit non-zero.
"""


class QuadModellingError(Exception):
    """Base class of every error this package raises on purpose."""


class DataError(QuadModellingError, ValueError):
    """A flight log, CSV, MATLAB file or bag holds data that cannot be used."""


class ConfigError(QuadModellingError, ValueError):
    """A vehicle config, mapping file or parameter is missing or invalid."""


class BagError(QuadModellingError, OSError):
    """An MCAP bag cannot be read or written (corrupt, truncated, missing topic)."""


class ModelError(QuadModellingError, ValueError):
    """A model file is invalid or does not fit the vehicle/variables asked for."""


class OutputExistsError(QuadModellingError, FileExistsError):
    """An output path exists and --force was not given."""
