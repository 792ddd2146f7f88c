"""Each command of ``pkmcal``, as a library function: read the user's files, check the
outputs before any work, compute, write the outputs all or none (:mod:`pkmcal.io.atomic`),
and return what there is to say as a :class:`~pkmcal.report.summary.Summary`. The CLI
(:mod:`pkmcal.cli`) parses its arguments, calls one of these and prints the summary; a Python
user calls the same functions.

Problems with the input raise :class:`~pkmcal.errors.InputError` naming the file, row,
column, key or option (the CLI's exit 2).
"""
