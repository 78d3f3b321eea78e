"""The model: the cell, the packing, the neighbour search, the contact law and the walls, and the
energy as a function of a flat position vector (the objective the engines minimize)."""
