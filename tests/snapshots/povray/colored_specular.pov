#version 3.7;
global_settings { assumed_gamma 1.0 ambient_light 1 max_trace_level 2 adc_bailout 0 }
camera { perspective location <0, 0, -2.5> right <1, 0, 0> up <0, 1, 0> direction <-0.5/48, 0.5/48, 2.5> }
#switch (frame_number)
#case (1)
  light_source { <4, 6, -3> color rgb 1 }
  sphere { <-0.5, -0.2, 5>, 0.7 pigment { rgb 1 } finish { ambient 0.1 diffuse 0.6 phong 1 phong_size 8 } }
  sphere { <0.8, 0, 6>, 0.8 pigment { rgb 1 } finish { ambient 0 diffuse 0 phong 0.2 phong_size 8 reflection { rgb 0.1 } } }
  plane { <0, 1, 0>, -1 pigment { rgb 1 } finish { ambient 0.05 diffuse 0.4 } }
#break
#case (2)
  light_source { <4, 6, -3> color rgb 0.9 }
  sphere { <-0.5, -0.2, 5>, 0.7 pigment { rgb 1 } finish { ambient 0.08 diffuse 0.45 phong 0.8 phong_size 8 } }
  sphere { <0.8, 0, 6>, 0.8 pigment { rgb 1 } finish { ambient 0.05 diffuse 0.5 phong 0.6 phong_size 8 reflection { rgb 0.2 } } }
  plane { <0, 1, 0>, -1 pigment { rgb 1 } finish { ambient 0.05 diffuse 0.4 } }
#break
#case (3)
  light_source { <4, 6, -3> color rgb 0.8 }
  sphere { <-0.5, -0.2, 5>, 0.7 pigment { rgb 1 } finish { ambient 0 diffuse 0 phong 0.2 phong_size 8 } }
  sphere { <0.8, 0, 6>, 0.8 pigment { rgb 1 } finish { ambient 0.05 diffuse 0.5 phong 1 phong_size 8 reflection { rgb 0.3 } } }
  plane { <0, 1, 0>, -1 pigment { rgb 1 } finish { ambient 0.05 diffuse 0.35 } }
#break
#end
