"""The commands (sfc-simulate, sfc-reconstruct, sfc-design, sfc-export, sfc-bench's sibling tools) and what
they share: composing configs, checking them before a run, the lines a run prints."""
