"""The heights as functions of the parameters a solver fits (kind ``representation``; the contract:
framework/core/contracts/representation.py): the free grids ``pixels`` and ``wavelets`` here, the
print's beads ``tracks`` in framework/tracks/."""
