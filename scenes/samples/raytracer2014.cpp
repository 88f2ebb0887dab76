// A sample solution of the 2014 edition of the exercise (Informatik I, problem 13.1), written for
// minirt's tests and `make demo`. It has three bugs real solutions have, one a line each below:
// its secondary rays start 1e-4 along the ray (the edition says 1e-3), its primary rays start on the
// pixel plane (the edition's start at the camera) and go through pixel corners (the edition's: centres).
// minirt builds it through the 2014 interface: Scene(camera, light, light colour, width, height),
// add_shape(Shape(type, v, d, ambient, diffuse, reflection)), raytrace(bitmap, depth).
#include <cmath>
#include <vector>

#include "bitmap.h"
#include "vector3.h"

#define OFFSET 1e-4       // the edition: 1e-3
#define PIXEL 0.0         // the edition: 0.5, the pixel's centre
#define FROM_PLANE 1      // the edition: 0, rays from the camera

enum ShapeType { BALL, PLANE };

struct Ray {
    Vector origin, direction;
    Ray(const Vector& o, const Vector& d) : origin(o), direction(d.Normalized()) {}
};

class Shape {
public:
    Shape(ShapeType type, const Vector& v, double d, const Color& ambient, const Color& diffuse, const Color& reflection)
        : type_(type), v_(type == PLANE ? v.Normalized() : v), d_(type == PLANE ? d / v.Length() : d),
          ambient_(ambient), diffuse_(diffuse), reflection_(reflection) {}

    // The smallest positive root (the 2014 edition sees a ball from inside).
    bool Intersect(const Ray& ray, double& t) const {
        if (type_ == PLANE) {
            double denom = ray.direction * v_;
            if (denom == 0) return false;
            t = (d_ - ray.origin * v_) / denom;
            return t > 0;
        }
        Vector w = ray.origin - v_;
        double b = w * ray.direction, disc = b * b - (w * w - d_ * d_);
        if (disc < 0) return false;
        double sq = std::sqrt(disc);
        t = -b - sq;
        if (t > 0) return true;
        t = -b + sq;
        return t > 0;
    }
    Vector GetNormal(const Vector& at) const { return type_ == PLANE ? v_ : (at - v_) / d_; }
    const Color& ambient() const { return ambient_; }
    const Color& diffuse() const { return diffuse_; }
    const Color& reflection() const { return reflection_; }

private:
    ShapeType type_;
    Vector v_;
    double d_;
    Color ambient_, diffuse_, reflection_;
};

class Scene {
public:
    Scene(const Vector& camera, const Vector& light, const Color& light_color, int width, int height)
        : camera_(camera), light_(light), light_color_(light_color), width_(width), height_(height) {}

    void add_shape(const Shape& s) { shapes_.push_back(s); }

    void raytrace(Bitmap& bitmap, int depth) const {
        for (int y = 0; y < height_; ++y)
            for (int x = 0; x < width_; ++x) {
                Vector p((x + PIXEL) / width_ - 0.5, -(y + PIXEL) / height_ + 0.5, 0);
                bitmap(x, y) = Trace(Ray(FROM_PLANE ? p : camera_, p - camera_), depth);
            }
    }

private:
    const Shape* Closest(const Ray& ray, double& t) const {
        const Shape* best = nullptr;
        t = INFINITY;
        for (const Shape& s : shapes_) {
            double ts;
            if (s.Intersect(ray, ts) && ts < t) { t = ts; best = &s; }
        }
        return best;
    }

    Color Trace(const Ray& ray, int depth) const {
        double t;
        const Shape* s = Closest(ray, t);
        if (!s) return Black;  // no background in 2014
        Vector p = ray.origin + ray.direction * t, n = s->GetNormal(p);
        Color c = s->ambient();
        Vector to_light = light_ - p;
        double dist = to_light.Length();
        Vector l = to_light / dist;
        Vector r = ray.direction - n * (2 * (ray.direction * n));
        Ray shadow(p + l * OFFSET, l);
        bool blocked = false;
        for (const Shape& o : shapes_) {
            double ts;
            if (o.Intersect(shadow, ts) && ts < dist) blocked = true;
        }
        if (!blocked) {
            double rs = r * l;
            c += light_color_ * s->diffuse() * float(l * n);
            if (rs > 0) c += light_color_ * s->reflection() * float(std::pow(rs, 16));
        }
        if (depth > 0) {
            Vector rd = r.Normalized();
            c += s->reflection() * Trace(Ray(p + rd * OFFSET, rd), depth - 1);
        }
        return c;
    }

    Vector camera_, light_;
    Color light_color_;
    int width_, height_;
    std::vector<Shape> shapes_;
};

int main() {
    Scene scene(Vector(0, 0, -2), Vector(10, 10, -1), White, 256, 256);
    scene.add_shape(Shape(BALL, Vector(0, 0, 4), 0.5, Color(0.1f, 0, 0), Color(0.8f, 0, 0), Black));
    Bitmap bitmap(256, 256);
    scene.raytrace(bitmap, 3);
    return bitmap.Save("raytracer.bmp") ? 0 : 1;
}
