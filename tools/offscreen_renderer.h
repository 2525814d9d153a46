// MuJoCo's renderer without a GPU or a display: an OSMesa (software OpenGL) context made current
// on this thread, MuJoCo's offscreen framebuffer of the frame's size, and frames read back as RGB
// rows, top row first. One renderer per program: OSMesa's context belongs to the calling thread.
#pragma once

#include <mujoco/mujoco.h>

#include <functional>
#include <string>
#include <utility>
#include <vector>

namespace farm::tools {

class OffscreenRenderer {
 public:
  // Throws std::runtime_error when OSMesa cannot make a context of this size.
  OffscreenRenderer(int width, int height);
  ~OffscreenRenderer();
  OffscreenRenderer(const OffscreenRenderer&) = delete;
  OffscreenRenderer& operator=(const OffscreenRenderer&) = delete;

  int width() const { return width_; }
  int height() const { return height_; }

  // Takes a copy of `m` to draw with (meshes, textures and height fields uploaded; the offscreen
  // buffer sized to the frame). Call again when the model changes (a new episode on another terrain).
  void set_model(const mjModel* m);
  // Clip planes for a camera this far from what it looks at (not the model's extent: an arena, a
  // height field, a microbot in millimetres).
  void set_camera_distance(double distance);
  const mjModel* model() const { return model_; }

  // Takes the pose of `d` (a simulation of the model set): its qpos and mocap poses, with this
  // renderer's own kinematics, so the simulation is only read. Returns the pose's data (body
  // frames for a camera to follow).
  const mjData* pose(const mjData* d);
  // Text in a corner of the frame: a column of names and one of values, a line each.
  struct Overlay {
    std::string names, values;
  };
  // Draws the pose from cam; `decorate` may add geoms to the scene (markers). With text, a panel
  // along the bottom of the frame holds the columns side by side (the scene above it, never
  // covered). rgb: width x height x 3 bytes.
  void render(mjvCamera& cam, const std::function<void(mjvScene&)>& decorate, const std::vector<Overlay>& columns,
              unsigned char* rgb);

  // The last render()'s scene pixels (the text panel left out) that show geoms of the bodies for
  // which `of_body` is true (the scene drawn again with and without them), and their share.
  struct Coverage {
    int64_t pixels = 0;
    double share = 0;
  };
  Coverage coverage(const std::function<bool(int body)>& of_body);

  // The overlay's columns for this frame's size: `first` (the episode, its step and return), then
  // the rows (name, value) in as few columns as the panel's height allows (at most half the frame)
  // and no more than its width does (each column as wide as its widest name and a short value).
  // Rows past those columns are left out, the last row shown saying how many ("+N more").
  std::vector<Overlay> layout(const Overlay& first, const std::vector<std::pair<std::string, std::string>>& rows) const;

  // Rows of the last render()'s overlay that are wider than their column even after wrapping (a
  // name or a single word too wide): they run past the column's edge.
  int cut_rows() const { return cut_rows_; }

 private:
  void read_rgb(unsigned char* rgb);
  // The columns with each value too wide for its cell (the frame's width over the columns) wrapped
  // at its spaces onto rows of its own, so that no text runs past the frame's edge.
  std::vector<Overlay> fit_columns(const std::vector<Overlay>& columns) const;
  int text_width(const std::string& text) const;  // pixels, in the overlay's font
  mutable int cut_rows_ = 0;                      // of the last render()'s overlay: rows still wider than their column

  int width_, height_;
  void* osmesa_ = nullptr;  // OSMesaContext
  std::vector<unsigned char> window_;
  mjModel* model_ = nullptr;
  mjData* data_ = nullptr;  // the pose drawn
  mjvScene scene_;
  mjvOption option_;
  mjrContext context_;
  bool have_context_ = false;
  std::vector<unsigned char> rows_;
  mjrRect scene_viewport_{0, 0, 0, 0};  // where the last render() drew the scene
};

}  // namespace farm::tools
