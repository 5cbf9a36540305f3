"""Independent truths: code that shares nothing with the model it scores.

Modules here generate or check data without importing the package's model
code (path solver, BSDFs, FMCW synthesiser, effects library, residual loop,
Mitsuba / Dr.Jit), so that a test built on them cannot pass merely because
the model and the truth share a mistake.

=========================  =================================================
``undeclared``             realistic test captures with planted sensor and
                           scene effects (a room with corner reflectors):
                           :func:`~.undeclared.make_case`,
                           :func:`~.undeclared.suite`,
                           :func:`~.undeclared.write_coloradar_run`
=========================  =================================================
"""
