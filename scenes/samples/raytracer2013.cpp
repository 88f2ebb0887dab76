// A sample solution of the 2013 edition of the exercise (Informatik I, problem 13.1), in the problem set's
// interface: Ray, an abstract Shape with Intersect and GetNormal, Ball, Plane, and Scene with AddShape and
// TraceRay. Its constructors are its own (the problem set leaves them to the student), so minirt builds
// its scenes through the course's adapter (adapter2013.cpp). It follows the problem set literally.
#include <cmath>
#include <vector>

#include "bitmap.h"
#include "vector3.h"

struct Ray {
    Vector start, dir;
    Ray(const Vector& s, const Vector& d) : start(s), dir(d.Normalized()) {}
};

struct Material {
    Color ambient, diffuse, specular, reflection;
};

class Shape {
public:
    explicit Shape(const Material& m) : material(m) {}
    virtual ~Shape() {}
    virtual bool Intersect(const Ray& ray, double& t) const = 0;
    virtual Vector GetNormal(const Vector& at) const = 0;
    Material material;
};

class Ball : public Shape {
public:
    Ball(const Vector& c, double r, const Material& m) : Shape(m), center(c), radius(r) {}
    bool Intersect(const Ray& ray, double& t) const {
        Vector v = ray.start - center;
        double b = v * ray.dir, disc = b * b - v * v + radius * radius;
        if (disc < 0) return false;
        t = -b - std::sqrt(disc);  // only the smaller root, provided it is not negative (Appendix 2)
        return t > 0;
    }
    Vector GetNormal(const Vector& at) const { return (at - center) / radius; }
    Vector center;
    double radius;
};

class Plane : public Shape {
public:
    Plane(const Vector& n, double a, const Material& m) : Shape(m), normal(n.Normalized()), distance(a / n.Length()) {}
    bool Intersect(const Ray& ray, double& t) const {
        double dn = ray.dir * normal;
        if (dn == 0) return false;
        t = (distance - ray.start * normal) / dn;
        return t > 0;
    }
    Vector GetNormal(const Vector&) const { return normal; }
    Vector normal;
    double distance;
};

class Scene {
public:
    Vector cameraVector, lightVector;
    Color lightColor, backgroundColor;
    Scene(Vector camera, Vector light, Color lc, Color bc)
        : cameraVector(camera), lightVector(light), lightColor(lc), backgroundColor(bc) {}
    void AddShape(Shape* shape) { shapes.push_back(shape); }

    Color TraceRay(const Ray& ray, int iter) const {
        Color color = Black;
        double t;
        const Shape* s = Intersect(ray, t);
        if (!s) return color;
        color = color + s->material.ambient;
        Vector hit = ray.start + ray.dir * t, n = s->GetNormal(hit);
        Ray shadow(hit + n * 1e-6, lightVector - hit);
        Vector r = ray.dir - n * (2 * (ray.dir * n));
        double ts;
        if (!Intersect(shadow, ts)) {
            color = color + lightColor * s->material.diffuse * float(shadow.dir * n);
            color = color + lightColor * s->material.specular * float(std::pow(r * shadow.dir, 8));
        }
        if (iter > 0) color = color + TraceRay(Ray(hit + n * 1e-6, r), iter - 1) * s->material.reflection;
        return color + backgroundColor;
    }

private:
    const Shape* Intersect(const Ray& ray, double& t) const {
        const Shape* best = nullptr;
        t = INFINITY;
        for (const Shape* s : shapes) {
            double t0;
            if (s->Intersect(ray, t0) && t0 < t) { best = s; t = t0; }
        }
        return best;
    }
    std::vector<Shape*> shapes;
};

int main() {
    const int size = 256;
    const double dist = 2;
    Scene scene(Vector(0, 0, -dist), Vector(10, 10, -1), White, Color(0.1f, 0, 0.1f));
    scene.AddShape(new Ball(Vector(0, 0, 4), 0.5, Material{Color(0.1f, 0, 0), Color(0.8f, 0, 0), White, Black}));
    Bitmap bitmap(size, size);
    for (int x = 0; x < size; ++x)
        for (int y = 0; y < size; ++y) {
            Vector planePoint(double(x) / size - 0.5, -double(y) / size + 0.5, 0);
            Ray ray(planePoint, planePoint - scene.cameraVector);
            bitmap(x, y) = AdjustColor(scene.TraceRay(ray, 3));
        }
    return bitmap.Save("raytracer.bmp") ? 0 : 1;
}
