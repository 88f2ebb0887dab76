// bitmap.h -- the course-side colour and bitmap, as minirt supplies them to a student's raytracer.cpp:
// Color (float r, g, b), its operators and named colours, AdjustColor, Bitmap(w, h), bitmap(x, y),
// GetWidth, GetHeight, Save. Header-only (every function inline): including it, or bitmap.cpp, twice
// is harmless. The bitmap keeps each pixel's colour as the program set it; minirt reads those floats.
#ifndef MINIRT_COURSE_BITMAP_H
#define MINIRT_COURSE_BITMAP_H

#include <cmath>
#include <cstdio>
#include <vector>

struct Color {
    float r, g, b;
    Color() : r(0), g(0), b(0) {}
    Color(float r_, float g_, float b_) : r(r_), g(g_), b(b_) {}
    Color operator+(const Color& o) const { return Color(r + o.r, g + o.g, b + o.b); }
    Color operator-(const Color& o) const { return Color(r - o.r, g - o.g, b - o.b); }
    Color operator*(const Color& o) const { return Color(r * o.r, g * o.g, b * o.b); }
    Color operator*(float k) const { return Color(r * k, g * k, b * k); }
    Color operator/(float k) const { return Color(r / k, g / k, b / k); }
    Color& operator+=(const Color& o) { r += o.r; g += o.g; b += o.b; return *this; }
    Color& operator-=(const Color& o) { r -= o.r; g -= o.g; b -= o.b; return *this; }
    Color& operator*=(const Color& o) { r *= o.r; g *= o.g; b *= o.b; return *this; }
    Color& operator*=(float k) { r *= k; g *= k; b *= k; return *this; }
    bool operator==(const Color& o) const { return r == o.r && g == o.g && b == o.b; }
    bool operator!=(const Color& o) const { return !(*this == o); }
};

inline Color operator*(float k, const Color& c) { return c * k; }

static const Color Black(0, 0, 0), White(1, 1, 1), Red(1, 0, 0), Green(0, 1, 0), Blue(0, 0, 1),
    Yellow(1, 1, 0), Cyan(0, 1, 1), Magenta(1, 0, 1), Gray(0.5f, 0.5f, 0.5f);

// Each channel clamped to [0, 1].
inline Color AdjustColor(const Color& c) {
    return Color(c.r < 0 ? 0 : (c.r > 1 ? 1 : c.r), c.g < 0 ? 0 : (c.g > 1 ? 1 : c.g),
                 c.b < 0 ? 0 : (c.b > 1 ? 1 : c.b));
}

class Bitmap {
public:
    Bitmap(int w, int h) : w_(w), h_(h), px_(static_cast<size_t>(w) * h) {}
    Color& operator()(int x, int y) { return px_.at(static_cast<size_t>(y) * w_ + x); }
    const Color& operator()(int x, int y) const { return px_.at(static_cast<size_t>(y) * w_ + x); }
    int GetWidth() const { return w_; }
    int GetHeight() const { return h_; }
    // A 24-bit BMP, each channel min(255, floor(256 c)) of the adjusted colour.
    bool Save(const char* filename) const {
        std::FILE* f = std::fopen(filename, "wb");
        if (!f) return false;
        int row = (3 * w_ + 3) / 4 * 4, size = 54 + row * h_;
        unsigned char head[54] = {'B', 'M'};
        auto put = [&](int at, int v) { for (int k = 0; k < 4; ++k) head[at + k] = (v >> (8 * k)) & 255; };
        put(2, size); put(10, 54); put(14, 40); put(18, w_); put(22, h_);
        head[26] = 1; head[28] = 24; put(34, row * h_);
        std::fwrite(head, 1, 54, f);
        std::vector<unsigned char> line(row, 0);
        for (int y = h_ - 1; y >= 0; --y) {
            for (int x = 0; x < w_; ++x) {
                Color c = AdjustColor((*this)(x, y));
                float v[3] = {c.b, c.g, c.r};
                for (int k = 0; k < 3; ++k) { int q = static_cast<int>(std::floor(256 * v[k])); line[3 * x + k] = q > 255 ? 255 : q; }
            }
            std::fwrite(line.data(), 1, row, f);
        }
        return std::fclose(f) == 0;
    }
private:
    int w_, h_;
    std::vector<Color> px_;
};

#endif
