"""Short scripts a researcher can copy, each writing one figure (docs/guide/examples.md shows them):

- ``reconstruct_from_python``: a reconstruction of a built-in scene from Python, truth against result;
- ``custom_regularizer``: a regulariser of one's own (Tikhonov L2) registered in the process and used;
- ``custom_operator``: an operator of one's own (a linear shadow) rendering data and reconstructing;
- ``design_through_lenses``: glass designed for a target seen through the paper's two lenses.

Run them all with ``python -m examples.gallery --out docs/gallery`` (CI does).
"""
