"""numpy reference implementations the compiled solver kernels are checked against (the former numpy path)."""
