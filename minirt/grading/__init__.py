"""Grading another tracer's image of a scene: grade (one image: a verdict, the rule settings that
explain it, a sentence each for the student), page (its HTML page), classroom (a whole class at once,
as independent jobs, with the class table, the CSV and the most common mistakes), program (a student's
program rendered over a suite of scenes, one diagnosis), program_page (its page, one file), program_class
(a class of programs, one row per student), hard_cases (a program's numerical failures on the fuzz
campaign's scenes).

May import: minirt.pages, minirt.harness, minirt.diagnose and below.
"""
