"""A component exported as an FMU (the slave side; :mod:`..fmu` is the other way, an FMU imported as a component).

Modules: :mod:`slave_fmi2` (the pythonfmu slave base, FMI 2.0), :mod:`slave_fmi3` (its pythonfmu3 twin, FMI 3.0),
:mod:`calls` (the co-simulation calls the two share), :mod:`description_fmi3` (a component's FMI 3.0
``modelDescription.xml``, its ports grouped into arrays; the FMI 2.0 one is the component's own,
:mod:`..model_description`), :mod:`bundle` (an FMU's slave script importing from its own copy of ``components``).
The body FMUs carry this folder in their copy of ``components``; it imports the component model and nothing else
of the project, and nothing here is imported at ``import rhi.components`` time.
"""
