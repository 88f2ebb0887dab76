// bitmap.cpp -- the course-side bitmap: everything is in bitmap.h.
#include "bitmap.h"
