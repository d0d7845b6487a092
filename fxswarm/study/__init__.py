"""Studies of the control law: settling time against initial error per controller
variant (``fxswarm sweep``), and the discretisation floor (``benchmarks/``)."""
