"""Errors the store raises; the web app maps them to HTTP status codes (404, 409, 400)."""


class StoreError(Exception):
    """Base class: the message is meant for the person or program that asked."""


class NotFound(StoreError):
    pass


class Conflict(StoreError):
    pass


class InvalidInput(StoreError):
    pass
