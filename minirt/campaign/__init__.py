"""The adversarial campaign behind ``minirt fuzz``: families of generated hard scenes (families),
random scenes of many balls (generate), and the campaign itself (campaign): scene x oracle jobs, with
injected defects that a check must catch.

May import: minirt.pages, minirt.harness and below.
"""
