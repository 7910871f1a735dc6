"""Envelope codes of moved samples cover the later samples they are made from.

The time offsets (:class:`replay.time_offsets.StreamAligner`) build each moved IMU's sample
at ``t`` from its raw samples around ``t − τ``; with ``τ < 0`` (the IMU sees the motion
later than the reference) that reaches up to ``ceil(|τ|·fs)`` samples past ``t``, plus the
interpolation kernel's half support. An impact that reaches the reference at sample ``m``
is then already in the moved IMU's samples before ``m``, while the operating envelope,
decided on the moved samples (:mod:`fdi.envelope`), flags it only from ``m`` on. Measured on
erle flight 41 (IMU2 at −9.65 ms, linear interpolation): two of the three held-out alarms
at 1/h were raised one sample before a shock was flagged.

:class:`LeadHold` gives every sample the union of its own code and the codes of the next
``lead`` samples (``codes[k] | … | codes[k + lead]``): a sample made from samples out of the
envelope is out of it. It holds the last ``lead`` samples of each block back until the next
block (or the end of the source) arrives, so a stream fed in pieces gets the same codes as
the whole flight at once; the answers come ``lead`` sample periods later. ``lead = 0`` (no
sample moved forward in time) changes nothing.
"""

from __future__ import annotations

import numpy as np

from replay.flight_data import Flight, concat_flights, flight_rows

__all__ = ["LeadHold", "dilate_back"]


def dilate_back(codes: np.ndarray, lead: int) -> np.ndarray:
    """``out[k] = codes[k] | codes[k+1] | … | codes[k+lead]`` (as far as the array goes).

    Parameters
    ----------
    codes : ndarray of int, shape (N,)
    lead : int
        Samples ahead (≥ 0).
    """
    c = np.asarray(codes, dtype=np.int64)
    out = c.copy()
    for j in range(1, min(int(lead), c.shape[0] - 1) + 1):
        out[:-j] |= c[j:]
    return out


class LeadHold:
    """Hold back ``lead`` samples so that each one's envelope code covers the next ``lead``.

    Parameters
    ----------
    lead : int
        Samples a moved sample reaches ahead (module docstring).
    """

    def __init__(self, lead: int) -> None:
        self.lead = max(int(lead), 0)
        self._piece: Flight | None = None
        self._codes = np.zeros(0, dtype=np.int64)

    def push(self, piece: Flight, codes: np.ndarray, *, final: bool = False
             ) -> tuple[Flight | None, np.ndarray]:
        """The samples that can be monitored now and their codes.

        Parameters
        ----------
        piece : Flight
            The next moved samples, in time order.
        codes : ndarray of int, shape (B,)
            Their envelope codes, as decided on them.
        final : bool
            The end of the source: everything held goes out.

        Returns
        -------
        piece : Flight or None
            The samples released (None: all held).
        codes : ndarray of int
            Their codes, each the union over itself and the next ``lead`` samples known.
        """
        codes = np.asarray(codes, dtype=np.int64)
        if self._piece is not None and self._piece.t.shape[0]:
            whole = concat_flights([self._piece, piece])
            allc = np.concatenate([self._codes, codes])
        else:
            whole, allc = piece, codes
        n = whole.t.shape[0]
        out_n = n if final else max(n - self.lead, 0)
        dil = dilate_back(allc, self.lead)
        self._piece = flight_rows(whole, slice(out_n, n))
        self._codes = allc[out_n:]
        if out_n == 0:
            return None, dil[:0]
        return flight_rows(whole, slice(0, out_n)), dil[:out_n]

    @property
    def holding(self) -> bool:
        """Samples are held back."""
        return self._piece is not None and self._piece.t.shape[0] > 0

    def release(self) -> tuple[Flight | None, np.ndarray]:
        """Everything held, at the end of the source (no later sample will come)."""
        if not self.holding:
            return None, self._codes[:0]
        piece, codes = self._piece, dilate_back(self._codes, self.lead)
        self._piece, self._codes = None, self._codes[:0]
        return piece, codes
