"""What accuracy costs in time: each backend's accuracy knob turned, time and error measured on one
scene, the Pareto front and the answer to "what does error below 1/255 cost".

May import: minirt.pages, minirt.harness and below.
"""
