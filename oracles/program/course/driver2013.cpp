// The 2013 edition's driver: the student's raytracer.cpp, then the course's adapter (adapter.cpp), which
// builds the scene with the student's own classes and traces one pixel's primary ray:
//   void minirt_scene(const Vector& camera, const Vector& light, const Color& light_color,
//                     const Color& background);
//   void minirt_ball(const Vector& center, double radius, const MinirtMaterial& m);
//   void minirt_plane(const Vector& normal, double distance, const MinirtMaterial& m);
//   Color minirt_pixel(int x, int y, int width, int height, int depth);  // the colour before AdjustColor
// for the scene in argv[1]; the pixels' colours written to argv[2] as a PFM.
#include "bitmap.h"
#include "vector3.h"
struct MinirtMaterial { Color ambient, diffuse, specular, reflection; };
#define main minirt_student_main
#include "raytracer.cpp"
#undef main
#include "adapter.cpp"
#include "scene_io.h"

int main(int argc, char** argv) {
    const MinirtScene s = minirt_scene_or_exit(argc, argv);
    minirt_scene(Vector(s.camera[0], s.camera[1], s.camera[2]), Vector(s.light[0], s.light[1], s.light[2]),
                 minirt_color(s.light_color), minirt_color(s.background));
    for (const MinirtShape& sh : s.shapes) {
        MinirtMaterial m{minirt_color(sh.ambient), minirt_color(sh.diffuse), minirt_color(sh.specular),
                         minirt_color(sh.reflection)};
        if (sh.kind == 0) minirt_ball(Vector(sh.v[0], sh.v[1], sh.v[2]), sh.d, m);
        else minirt_plane(Vector(sh.v[0], sh.v[1], sh.v[2]), sh.d, m);
    }
    std::vector<Color> px(static_cast<size_t>(s.width) * s.height);
    for (int y = 0; y < s.height; ++y)
        for (int x = 0; x < s.width; ++x) px[static_cast<size_t>(y) * s.width + x] = minirt_pixel(x, y, s.width, s.height, s.depth);
    bool ok = minirt_write_pfm(argv[2], s.width, s.height, [&](int x, int y, float* out) {
        const Color& c = px[static_cast<size_t>(y) * s.width + x]; out[0] = c.r; out[1] = c.g; out[2] = c.b; });
    return ok ? 0 : 4;
}
