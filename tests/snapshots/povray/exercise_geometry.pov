#version 3.7;
global_settings { assumed_gamma 1.0 ambient_light 1 max_trace_level 4 adc_bailout 0 }
camera { perspective location <0, 0, -2> right <1, 0, 0> up <0, 1, 0> direction <-0.5/48, 0.5/48, 2> }
#switch (frame_number)
#case (1)
  light_source { <10, 10, -1> color rgb <1, 1, 1> }
  sphere { <0, 0, 4>, 0.5 pigment { rgb <0.7, 0.1, 0.1> } finish { ambient rgb <0.28571428571428575, 0, 1> diffuse 1 phong 0.5 phong_size 8 reflection { rgb <0.2, 0.2, 0.2> } } }
  plane { <0, 1, 0>, -1 pigment { rgb 1 } finish { ambient rgb <0.15000000000000002, 0.05, 0.15000000000000002> diffuse 0.5 } }
#break
#case (2)
  sphere { <0, 0, 4>, 0.5
    pigment { average pigment_map {
      [1 function { floor(((x) - (-1)) * 512) / 1024 } color_map { [0 rgb 0] [1 rgb <3, 0, 0>] }]
      [1 function { ((x) - (-1)) * 512 - floor(((x) - (-1)) * 512) } color_map { [0 rgb 0] [1 rgb <0, 3, 0>] }]
      [1 function { floor(((y) - (-2)) * 409.6) / 1024 } color_map { [0 rgb 0] [1 rgb <0, 0, 3>] }]
    } } finish { ambient 1 diffuse 0 } }
  plane { <0, 1, 0>, -1
    pigment { average pigment_map {
      [1 function { floor(((x) - (0)) * 1024) / 1024 } color_map { [0 rgb 0] [1 rgb <3, 0, 0>] }]
      [1 function { ((x) - (0)) * 1024 - floor(((x) - (0)) * 1024) } color_map { [0 rgb 0] [1 rgb <0, 3, 0>] }]
      [1 function { floor(((y) - (0)) * 1024) / 1024 } color_map { [0 rgb 0] [1 rgb <0, 0, 3>] }]
    } } finish { ambient 1 diffuse 0 } }
#break
#case (3)
  sphere { <0, 0, 4>, 0.5
    pigment { average pigment_map {
      [1 function { ((y) - (-2)) * 409.6 - floor(((y) - (-2)) * 409.6) } color_map { [0 rgb 0] [1 rgb <3, 0, 0>] }]
      [1 function { floor(((z) - (3)) * 512) / 1024 } color_map { [0 rgb 0] [1 rgb <0, 3, 0>] }]
      [1 function { ((z) - (3)) * 512 - floor(((z) - (3)) * 512) } color_map { [0 rgb 0] [1 rgb <0, 0, 3>] }]
    } } finish { ambient 1 diffuse 0 } }
  plane { <0, 1, 0>, -1
    pigment { average pigment_map {
      [1 function { ((y) - (0)) * 1024 - floor(((y) - (0)) * 1024) } color_map { [0 rgb 0] [1 rgb <3, 0, 0>] }]
      [1 function { floor(((z) - (0)) * 1024) / 1024 } color_map { [0 rgb 0] [1 rgb <0, 3, 0>] }]
      [1 function { ((z) - (0)) * 1024 - floor(((z) - (0)) * 1024) } color_map { [0 rgb 0] [1 rgb <0, 0, 3>] }]
    } } finish { ambient 1 diffuse 0 } }
#break
#case (4)
  sphere { <0, 0, 4>, 0.5
    pigment { average pigment_map {
      [1 function { floor(((sqrt(x*x + y*y + (z + 2)*(z + 2)) * z / (z + 2)) - (0.5)) * 292.57142857142856) / 1024 } color_map { [0 rgb 0] [1 rgb <3, 0, 0>] }]
      [1 function { ((sqrt(x*x + y*y + (z + 2)*(z + 2)) * z / (z + 2)) - (0.5)) * 292.57142857142856 - floor(((sqrt(x*x + y*y + (z + 2)*(z + 2)) * z / (z + 2)) - (0.5)) * 292.57142857142856) } color_map { [0 rgb 0] [1 rgb <0, 3, 0>] }]
      [1 function { 0.00048828125 } color_map { [0 rgb 0] [1 rgb <0, 0, 3>] }]
    } } finish { ambient 1 diffuse 0 } }
  plane { <0, 1, 0>, -1
    pigment { average pigment_map {
      [1 function { floor(((sqrt(x*x + y*y + (z + 2)*(z + 2)) * z / (z + 2)) - (0)) * 1024) / 1024 } color_map { [0 rgb 0] [1 rgb <3, 0, 0>] }]
      [1 function { ((sqrt(x*x + y*y + (z + 2)*(z + 2)) * z / (z + 2)) - (0)) * 1024 - floor(((sqrt(x*x + y*y + (z + 2)*(z + 2)) * z / (z + 2)) - (0)) * 1024) } color_map { [0 rgb 0] [1 rgb <0, 3, 0>] }]
      [1 function { 0.0009765625 } color_map { [0 rgb 0] [1 rgb <0, 0, 3>] }]
    } } finish { ambient 1 diffuse 0 } }
#break
#end
