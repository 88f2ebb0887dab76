"""Grading another tracer's image of a scene: grade (one image: a verdict, the rule settings that
explain it, a sentence each for the student), page (its HTML page), classroom (a whole class at once,
as independent jobs, with the class table, the CSV and the most common mistakes), program (a student's
program rendered over a suite of scenes, one diagnosis) and program_page (its page, one file).

May import: minirt.pages, minirt.harness, minirt.diagnose and below.
"""
