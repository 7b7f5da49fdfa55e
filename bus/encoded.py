"""A message that is already CDR bytes: :class:`Encoded`.

A node that can write an output's bytes straight from its values (:mod:`bus.packed`) hands
its member an :class:`Encoded` instead of a rosbags message: the member sends the bytes as
they are (no message tree is built and walked to encode it). Given its type, it still reads
as the message: its fields are those of the bytes decoded, decoded once, on first use (a
test or a log that looks at what a node returned), so a caller need not know which it got.
A node that still holds the values may give a function that builds the message from them
(:mod:`bus.made`: the object decoding the bytes gives), called instead of decoding where a
reader in the same process wants the message (:meth:`Encoded.made`).
"""
from __future__ import annotations


class Encoded:
    """``data``: a message's CDR bytes; ``msgtype``: its ROS type, for reading its fields
    (None: bytes only); ``make``: a function of no arguments that builds the message these
    bytes decode to from the values they were packed from (None: decoded)."""
    __slots__ = ("data", "msgtype", "_msg", "_make")

    def __init__(self, data: bytes, msgtype: str | None = None, make=None) -> None:
        self.data = data
        self.msgtype = msgtype
        self._msg = None
        self._make = make

    def made(self):
        """The message built from its values (``make``), once; None without ``make``."""
        return self.decoded() if self._make is not None else None

    def decoded(self):
        """The message these bytes are (:func:`bus.codec.decode`), decoded once (or built
        from its values: ``make``)."""
        if self._msg is None:
            if self._make is not None:
                self._msg = self._make()
                return self._msg
            if self.msgtype is None:
                raise TypeError("encoded bytes of no known type: no fields to read")
            from .codec import decode           # (codec imports packed, which may use this)
            self._msg = decode(self.data, self.msgtype)
        return self._msg

    def __getattr__(self, name: str):
        # (only for names not in __slots__: the message's fields, __msgtype__ ...)
        if name.startswith("__") and name != "__msgtype__":
            raise AttributeError(name)
        return getattr(self.decoded(), name)

    def __eq__(self, other) -> bool:
        if type(other) is Encoded:
            return self.data == other.data
        return self.decoded() == other

    __hash__ = None                             # (equal to a message, which has none)

    def __repr__(self) -> str:
        return f"Encoded({self.msgtype or 'bytes'}, {len(self.data)} bytes)"
