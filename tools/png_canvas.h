// A small RGB canvas with the few shapes the trajectory plots need, written as PNG through zlib.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace farm::tools {

struct Rgb {
  uint8_t r = 0, g = 0, b = 0;
};

class Canvas {
 public:
  Canvas(int width, int height, Rgb background);
  int width() const { return w_; }
  int height() const { return h_; }
  void pixel(int x, int y, Rgb c);
  void fill_rect(double x0, double y0, double x1, double y1, Rgb c);
  void fill_circle(double cx, double cy, double r, Rgb c);
  // Convex polygon given as n points (xs, ys).
  void fill_polygon(const std::vector<double>& xs, const std::vector<double>& ys, Rgb c);
  void line(double x0, double y0, double x1, double y1, double width, Rgb c);
  // Throws std::runtime_error naming the file when it cannot be written.
  void write_png(const std::string& path) const;

 private:
  int w_, h_;
  std::vector<uint8_t> rgb_;
};

}  // namespace farm::tools
