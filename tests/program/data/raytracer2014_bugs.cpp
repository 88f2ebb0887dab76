// A solution of the 2014 edition of the exercise (Informatik I, problem 13.1) written for minirt's tests,
// with four bugs real solutions have, each marked BUG below:
//   - secondary rays start 1e-4 along their direction (the edition: 1e-3);
//   - primary rays start on the pixel plane, not at the camera;
//   - they go through the pixel's corner, not its centre;
//   - a ball's far root is never taken: from inside, a ball is invisible (the edition: smallest positive root).
// The tests grade it over minirt's suite and expect exactly these four rules named:
// offset = 0.0001, ray_origin = image-plane, pixel_sample = corner, near_root_only = true.
#include <cmath>
#include <vector>

#include "bitmap.h"
#include "vector3.h"

enum ShapeType { BALL, PLANE };

const double EPSILON = 1e-4;  // BUG: the edition says 1e-3

struct Ray {
    Vector start, direction;
    Ray(Vector s, Vector d) : start(s), direction(d.Normalized()) {}
};

struct Shape {
    ShapeType type;
    Vector v;  // a ball's centre, a plane's normal (made of unit length)
    double d;  // a ball's radius, a plane's distance along the normal
    Color ambient, diffuse, reflection;

    Shape(ShapeType t, Vector v_, double d_, Color a, Color df, Color r)
        : type(t), v(v_), d(d_), ambient(a), diffuse(df), reflection(r) {
        if (type == PLANE) {
            double len = v.Length();
            v = v / len;
            d = d / len;
        }
    }

    bool intersect(const Ray& ray, double& t) const {
        if (type == PLANE) {
            double dn = ray.direction * v;
            if (dn == 0) return false;
            t = (d - ray.start * v) / dn;
            return t > 0;
        }
        Vector oc = ray.start - v;
        double b = 2 * (oc * ray.direction);
        double c = oc * oc - d * d;
        double disc = b * b - 4 * c;
        if (disc < 0) return false;
        t = (-b - std::sqrt(disc)) / 2;
        return t > 0;  // BUG: the far root, (-b + sqrt(disc)) / 2, is never tried
    }

    Vector get_normal(const Vector& p) const { return type == PLANE ? v : (p - v) / d; }
};

class Scene {
public:
    Scene(Vector camera, Vector light, Color light_color, int w, int h)
        : camera(camera), light(light), light_color(light_color), width(w), height(h) {}

    void add_shape(const Shape& s) { shapes.push_back(s); }

    const Shape* intersect(const Ray& ray, double& t) const {
        const Shape* hit = nullptr;
        t = HUGE_VAL;
        for (const Shape& s : shapes) {
            double ts;
            if (s.intersect(ray, ts) && ts < t) {
                t = ts;
                hit = &s;
            }
        }
        return hit;
    }

    Ray create_ray(int x, int y) const {
        Vector pixel(double(x) / width - 0.5, 0.5 - double(y) / height, 0);  // BUG: the corner, not + 0.5
        return Ray(pixel, pixel - camera);                                   // BUG: starts on the pixel plane
    }

    Color trace(const Ray& ray, int depth) const {
        double t;
        const Shape* s = intersect(ray, t);
        if (s == nullptr) return Black;
        Vector p = ray.start + ray.direction * t;
        Vector n = s->get_normal(p);
        Vector l = light - p;
        double light_dist = l.Length();
        l = l / light_dist;
        Vector r = ray.direction - 2 * (ray.direction * n) * n;
        Color color = s->ambient;
        Ray shadow(p + EPSILON * l, l);
        double ts;
        const Shape* blocker = intersect(shadow, ts);
        if (blocker == nullptr || ts >= light_dist) {
            color += light_color * s->diffuse * float(l * n);
            double rl = r * l;
            if (rl > 0) color += light_color * s->reflection * float(std::pow(rl, 16));
        }
        if (depth > 0) {
            Vector rd = r.Normalized();
            color += s->reflection * trace(Ray(p + EPSILON * rd, rd), depth - 1);
        }
        return color;
    }

    void raytrace(Bitmap& bitmap, int depth) const {
        for (int y = 0; y < height; ++y)
            for (int x = 0; x < width; ++x) bitmap(x, y) = trace(create_ray(x, y), depth);
    }

private:
    Vector camera, light;
    Color light_color;
    int width, height;
    std::vector<Shape> shapes;
};
