// The 2014 edition's driver: the student's raytracer.cpp built through the edition's interface,
//   Scene(camera, light, light colour, width, height); add_shape(Shape(type, v, d, ambient, diffuse,
//   reflection)) with type BALL or PLANE (v, d: a ball's centre and radius, a plane's normal and
//   distance); raytrace(bitmap, depth)
// for the scene in argv[1]; the bitmap's colours written to argv[2] as a PFM.
#include "bitmap.h"
#include "vector3.h"
#define main minirt_student_main
#include "raytracer.cpp"
#undef main
#include "scene_io.h"

int main(int argc, char** argv) {
    const MinirtScene s = minirt_scene_or_exit(argc, argv);
    Scene scene(Vector(s.camera[0], s.camera[1], s.camera[2]), Vector(s.light[0], s.light[1], s.light[2]),
                minirt_color(s.light_color), s.width, s.height);
    for (const MinirtShape& sh : s.shapes)
        scene.add_shape(Shape(sh.kind == 0 ? BALL : PLANE, Vector(sh.v[0], sh.v[1], sh.v[2]), sh.d,
                              minirt_color(sh.ambient), minirt_color(sh.diffuse), minirt_color(sh.reflection)));
    Bitmap bitmap(s.width, s.height);
    scene.raytrace(bitmap, s.depth);
    bool ok = minirt_write_pfm(argv[2], s.width, s.height, [&](int x, int y, float* out) {
        const Color& c = bitmap(x, y); out[0] = c.r; out[1] = c.g; out[2] = c.b; });
    return ok ? 0 : 4;
}
