"""Domain exceptions of the simulation core; translated to exit codes / HTTP only at the edges."""


class SimError(Exception):
    """Base class of the simulation core's errors."""


class SpecError(SimError, ValueError):
    """A task spec (or character file) is invalid; the message names the field and the rule."""


class CharacterError(SpecError):
    """A character data file is invalid."""
