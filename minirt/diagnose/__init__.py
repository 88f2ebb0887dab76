"""Diagnosis: which rule settings explain an image (a student's, or an oracle's colour buffer), by
searching rule space with the reference tracer. Used by grading (a student's image) and by the harness
(an oracle's image).

May import: minirt.reference, minirt.model and below.
"""
