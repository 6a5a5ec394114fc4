"""Running the core's progress generators (Qt-free).

The applications are generators that yield states with a ``fraction`` and
return their result (stardist-napari style); these two helpers are the only
places that unpack them.
"""

from __future__ import annotations


def drain(gen):
    """Run ``gen`` to its end; return its return value."""
    while True:
        try:
            next(gen)
        except StopIteration as stop:
            return stop.value


def relay(gen):
    """Re-yield each state as its progress fraction (a float) and then the
    state itself; return ``gen``'s return value. What a napari worker needs."""
    while True:
        try:
            state = next(gen)
        except StopIteration as stop:
            return stop.value
        yield float(state.fraction)
        yield state
