// scene_io.h -- minirt's side of a compiled program: the scene's data file and the float image.
// The data file (written by minirt.oracles.program.cpp.scene_data): "minirt-scene 1", then
//   width height max_depth
//   camera: x y z
//   light: x y z r g b
//   background: r g b
//   shape count, then per shape: kind (0 ball, 1 plane) v.x v.y v.z d, then ambient, diffuse, specular,
//   reflection (r g b each)
// numbers with 17 significant digits (a double reads back exactly). The image: a PFM (three float32
// channels, little-endian, rows bottom-up as PFM stores them), the colours as the program set them.
#ifndef MINIRT_SCENE_IO_H
#define MINIRT_SCENE_IO_H

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

struct MinirtColor { double r, g, b; };
struct MinirtShape { int kind; double v[3]; double d; MinirtColor ambient, diffuse, specular, reflection; };
struct MinirtScene {
    int width, height, depth;
    double camera[3], light[3];
    MinirtColor light_color, background;
    std::vector<MinirtShape> shapes;
};

static bool minirt_read_color(std::istream& in, MinirtColor& c) { return bool(in >> c.r >> c.g >> c.b); }

static bool minirt_read_scene(const char* path, MinirtScene& s) {
    std::ifstream in(path);
    std::string magic; int version = 0; size_t n = 0;
    if (!(in >> magic >> version) || magic != "minirt-scene" || version != 1) return false;
    if (!(in >> s.width >> s.height >> s.depth)) return false;
    if (!(in >> s.camera[0] >> s.camera[1] >> s.camera[2])) return false;
    if (!(in >> s.light[0] >> s.light[1] >> s.light[2]) || !minirt_read_color(in, s.light_color)) return false;
    if (!minirt_read_color(in, s.background) || !(in >> n)) return false;
    for (size_t k = 0; k < n; ++k) {
        MinirtShape sh;
        if (!(in >> sh.kind >> sh.v[0] >> sh.v[1] >> sh.v[2] >> sh.d)) return false;
        if (!minirt_read_color(in, sh.ambient) || !minirt_read_color(in, sh.diffuse)) return false;
        if (!minirt_read_color(in, sh.specular) || !minirt_read_color(in, sh.reflection)) return false;
        s.shapes.push_back(sh);
    }
    return true;
}

// The driver's start: the scene in argv[1] (argv[2]: where the colours go), or a message and exit status 3.
static MinirtScene minirt_scene_or_exit(int argc, char** argv) {
    MinirtScene s;
    if (argc != 3 || !minirt_read_scene(argv[1], s)) {
        std::fprintf(stderr, "minirt driver: cannot read the scene\n");
        std::exit(3);
    }
    return s;
}

// A MinirtColor as the course's Color (bitmap.h, included before this file).
static Color minirt_color(const MinirtColor& c) { return Color(float(c.r), float(c.g), float(c.b)); }

// pixel(x, y) gives three floats; y = 0 is the top row.
template <class Pixel>
static bool minirt_write_pfm(const char* path, int w, int h, Pixel pixel) {
    std::FILE* f = std::fopen(path, "wb");
    if (!f) return false;
    std::fprintf(f, "PF\n%d %d\n-1.0\n", w, h);
    std::vector<float> row(3 * static_cast<size_t>(w));
    for (int y = h - 1; y >= 0; --y) {
        for (int x = 0; x < w; ++x) pixel(x, y, &row[3 * static_cast<size_t>(x)]);
        std::fwrite(row.data(), sizeof(float), row.size(), f);
    }
    return std::fclose(f) == 0;
}

#endif
