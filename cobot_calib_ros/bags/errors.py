"""The one error the bag modules raise."""


class BagError(Exception):
    """A bag that cannot be read or written; str() names the file, the problem and what to do."""
