"""Co-simulation components of the rubber-hand model; each sub-package is one component.

The component model itself (variables, lifecycle, model description) lives in
this package's modules; components never import each other.
"""
