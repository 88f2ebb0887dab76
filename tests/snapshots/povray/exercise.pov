#version 3.7;
global_settings { assumed_gamma 1.0 ambient_light 1 max_trace_level 4 adc_bailout 0 }
camera { perspective location <0, 0, -2> right <1, 0, 0> up <0, 1, 0> direction <-0.5/48, 0.5/48, 2> }
light_source { <10, 10, -1> color rgb <1, 1, 1> }
sphere { <0, 0, 4>, 0.5 pigment { rgb <0.7, 0.1, 0.1> } finish { ambient rgb <0.28571428571428575, 0, 1> diffuse 1 phong 0.5 phong_size 8 reflection { rgb <0.2, 0.2, 0.2> } } }
plane { <0, 1, 0>, -1 pigment { rgb 1 } finish { ambient rgb <0.15000000000000002, 0.05, 0.15000000000000002> diffuse 0.5 } }
