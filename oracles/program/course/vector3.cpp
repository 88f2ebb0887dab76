// vector3.cpp -- the course-side vector: everything is in vector3.h.
#include "vector3.h"
