// vector3.h -- the course-side three-dimensional vector, as minirt supplies it: double x, y, z; + and -,
// scaling by a number, a * b the dot product (the pseudo-code's notation), Dot, Cross, Length, Normalized.
// Header-only (every function inline): including it, or vector3.cpp, twice is harmless.
#ifndef MINIRT_COURSE_VECTOR3_H
#define MINIRT_COURSE_VECTOR3_H

#include <cmath>

struct Vector {
    double x, y, z;
    Vector() : x(0), y(0), z(0) {}
    Vector(double x_, double y_, double z_) : x(x_), y(y_), z(z_) {}
    Vector operator+(const Vector& o) const { return Vector(x + o.x, y + o.y, z + o.z); }
    Vector operator-(const Vector& o) const { return Vector(x - o.x, y - o.y, z - o.z); }
    Vector operator-() const { return Vector(-x, -y, -z); }
    Vector operator*(double k) const { return Vector(x * k, y * k, z * k); }
    Vector operator/(double k) const { return Vector(x / k, y / k, z / k); }
    double operator*(const Vector& o) const { return x * o.x + y * o.y + z * o.z; }
    Vector& operator+=(const Vector& o) { x += o.x; y += o.y; z += o.z; return *this; }
    Vector& operator-=(const Vector& o) { x -= o.x; y -= o.y; z -= o.z; return *this; }
    Vector& operator*=(double k) { x *= k; y *= k; z *= k; return *this; }
    double Dot(const Vector& o) const { return *this * o; }
    Vector Cross(const Vector& o) const { return Vector(y * o.z - z * o.y, z * o.x - x * o.z, x * o.y - y * o.x); }
    double Length() const { return std::sqrt(*this * *this); }
    Vector Normalized() const { return *this / Length(); }
};

inline Vector operator*(double k, const Vector& v) { return v * k; }

#endif
