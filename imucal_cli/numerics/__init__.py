"""Numerics no library provides, each measured against the library that comes closest and
tested against it (DEVELOPERS.md, "What stayed home-made"): the Allan deviation accumulated
block by block (``allan``), segmented statistics of many segments at once (``segmented``),
and the checks every block-by-block accumulator shares (``blocks``). Arrays in, arrays out:
no files, no printing; they import numpy and ``errors`` only."""
