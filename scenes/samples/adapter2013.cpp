// The course's adapter for the 2013 edition (written once per course, not per student): it builds a ball,
// a plane and the scene with the student's own classes and traces one pixel's primary ray as the
// problem set's loop does. minirt compiles it after the student's raytracer.cpp (see README: "A program
// under test"); MinirtMaterial holds the four colours of a shape's material.
static Scene* minirt_the_scene = nullptr;

void minirt_scene(const Vector& camera, const Vector& light, const Color& light_color, const Color& background) {
    minirt_the_scene = new Scene(camera, light, light_color, background);
}

void minirt_ball(const Vector& center, double radius, const MinirtMaterial& m) {
    minirt_the_scene->AddShape(new Ball(center, radius, Material{m.ambient, m.diffuse, m.specular, m.reflection}));
}

void minirt_plane(const Vector& normal, double distance, const MinirtMaterial& m) {
    minirt_the_scene->AddShape(new Plane(normal, distance, Material{m.ambient, m.diffuse, m.specular, m.reflection}));
}

Color minirt_pixel(int x, int y, int width, int height, int depth) {
    Vector planePoint(double(x) / width - 0.5, -double(y) / height + 0.5, 0);
    Ray ray(planePoint, planePoint - minirt_the_scene->cameraVector);
    return minirt_the_scene->TraceRay(ray, depth);
}
