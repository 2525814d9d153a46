#include "offscreen_renderer.h"

#include <GL/osmesa.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <stdexcept>

namespace farm::tools {

namespace {

// Scene room for the model's own geoms plus a renderer's markers.
constexpr int kMaxSceneGeoms = 10000;
// A pixel whose channels differ by more than this between two passes changed.
constexpr int kPixelChange = 8;
// Clip planes in camera distances: near enough for a robot filling the frame, far enough for the
// floor to the horizon at the default elevations.
constexpr double kNearOfDistance = 0.01, kFarOfDistance = 100;
// The head light of a model that has no light (MuJoCo's default: ambient 0.1, diffuse 0.4).
constexpr float kBareAmbient = 0.35f, kBareDiffuse = 0.65f;
// The text panel's background.
constexpr float kPanelGrey = 0.12f;

// Text about 1/20 of the frame's height at most: the overlay must leave the robot in view.
int font_scale(int height) {
  if (height < 720) return mjFONTSCALE_100;
  if (height < 1080) return mjFONTSCALE_150;
  return mjFONTSCALE_200;
}

}  // namespace

OffscreenRenderer::OffscreenRenderer(int width, int height) : width_(width), height_(height) {
  if (width < 16 || height < 16 || width > 4096 || height > 4096)
    throw std::invalid_argument("frame size " + std::to_string(width) + "x" + std::to_string(height) +
                                " is outside 16x16 .. 4096x4096");
  OSMesaContext ctx = OSMesaCreateContextExt(OSMESA_RGBA, 24, 8, 0, nullptr);
  if (!ctx) throw std::runtime_error("OSMesa could not create an OpenGL context (libOSMesa, Debian's libosmesa6)");
  osmesa_ = ctx;
  // The window buffer only makes the context current; MuJoCo draws into its offscreen framebuffer.
  window_.assign(size_t(width) * height * 4, 0);
  if (!OSMesaMakeCurrent(ctx, window_.data(), GL_UNSIGNED_BYTE, width, height)) {
    OSMesaDestroyContext(ctx);
    osmesa_ = nullptr;
    throw std::runtime_error("OSMesa could not make its context current");
  }
  mjv_defaultScene(&scene_);
  mjv_defaultOption(&option_);
  mjr_defaultContext(&context_);
  rows_.resize(size_t(width) * height * 3);
}

OffscreenRenderer::~OffscreenRenderer() {
  if (have_context_) mjr_freeContext(&context_);
  mjv_freeScene(&scene_);
  if (data_) mj_deleteData(data_);
  if (model_) mj_deleteModel(model_);
  if (osmesa_) OSMesaDestroyContext(static_cast<OSMesaContext>(osmesa_));
}

void OffscreenRenderer::set_model(const mjModel* m) {
  if (have_context_) mjr_freeContext(&context_);
  have_context_ = false;
  mjv_freeScene(&scene_);
  if (data_) mj_deleteData(data_);
  data_ = nullptr;
  if (model_) mj_deleteModel(model_);
  model_ = mj_copyModel(nullptr, m);
  if (!model_) throw std::runtime_error("cannot copy the model to render it");
  data_ = mj_makeData(model_);
  if (!data_) throw std::runtime_error("cannot allocate the data to render the model");
  model_->vis.global.offwidth = width_;
  model_->vis.global.offheight = height_;
  // A model without lights of its own (the pendulums) is lit by a brighter head light.
  if (model_->nlight == 0) {
    for (int k = 0; k < 3; ++k) {
      model_->vis.headlight.ambient[k] = kBareAmbient;
      model_->vis.headlight.diffuse[k] = kBareDiffuse;
    }
  }
  mjv_makeScene(model_, &scene_, kMaxSceneGeoms);
  mjr_defaultContext(&context_);
  mjr_makeContext(model_, &context_, font_scale(height_));
  have_context_ = true;
  mjr_setBuffer(mjFB_OFFSCREEN, &context_);
  if (context_.currentBuffer != mjFB_OFFSCREEN)
    throw std::runtime_error("MuJoCo has no offscreen framebuffer in this OpenGL context");
  if (context_.offWidth < width_ || context_.offHeight < height_)
    throw std::runtime_error("MuJoCo's offscreen buffer is " + std::to_string(context_.offWidth) + "x" +
                             std::to_string(context_.offHeight) + ", smaller than the frame");
}

void OffscreenRenderer::read_rgb(unsigned char* rgb) {
  const mjrRect viewport{0, 0, width_, height_};
  mjr_readPixels(rows_.data(), nullptr, viewport, &context_);
  // OpenGL's rows run bottom up; video frames top down.
  const size_t row = size_t(width_) * 3;
  for (int y = 0; y < height_; ++y)
    std::memcpy(rgb + size_t(y) * row, rows_.data() + size_t(height_ - 1 - y) * row, row);
}

void OffscreenRenderer::set_camera_distance(double distance) {
  if (!model_) throw std::logic_error("OffscreenRenderer::set_camera_distance before set_model");
  // MuJoCo scales both planes by the model's extent when it sets up each frame's camera.
  const double extent = model_->stat.extent > 0 ? model_->stat.extent : 1.0;
  model_->vis.map.znear = float(kNearOfDistance * distance / extent);
  model_->vis.map.zfar = float(kFarOfDistance * distance / extent);
}

const mjData* OffscreenRenderer::pose(const mjData* d) {
  if (!have_context_) throw std::logic_error("OffscreenRenderer::pose before set_model");
  // The pose: positions and mocap bodies, then what drawing reads (frames, cameras and lights,
  // tendon paths). The simulation's own derived fields may be a physics step behind its qpos.
  std::copy(d->qpos, d->qpos + model_->nq, data_->qpos);
  std::copy(d->mocap_pos, d->mocap_pos + 3 * model_->nmocap, data_->mocap_pos);
  std::copy(d->mocap_quat, d->mocap_quat + 4 * model_->nmocap, data_->mocap_quat);
  data_->time = d->time;
  mj_kinematics(model_, data_);
  mj_comPos(model_, data_);
  mj_camlight(model_, data_);
  mj_tendon(model_, data_);
  return data_;
}

int OffscreenRenderer::text_width(const std::string& text) const {
  int w = 0;
  for (unsigned char c : text) w += c < 127 ? context_.charWidth[c] : context_.charWidth[int('?')];
  return w;
}

std::vector<OffscreenRenderer::Overlay> OffscreenRenderer::layout(
    const Overlay& first, const std::vector<std::pair<std::string, std::string>>& rows) const {
  if (!have_context_) throw std::logic_error("OffscreenRenderer::layout before set_model");
  const int cw = context_.charWidth[int('x')], ch = std::max(1, context_.charHeight);
  // The panel holds (3 r + 2) / 2 lines for r rows (render()), at most half the frame.
  const int per_column = std::max(3, (height_ / ch - 2) / 3);
  // A column fits its widest name, a value of 8 characters or its own, and the margins.
  int widest = 0;
  for (const auto& [name, value] : rows)
    widest = std::max(widest, text_width(name) + std::min(text_width(value), 8 * cw) + 6 * cw);
  const int n = int(rows.size());
  int columns = 0;
  while (columns < (n + per_column - 1) / per_column && width_ / (columns + 2) >= std::max(widest, 22 * cw)) ++columns;
  std::vector<Overlay> out{first};
  auto add = [](Overlay& to, const std::string& name, const std::string& value) {
    to.names += (to.names.empty() ? "" : "\n") + name;
    to.values += (to.values.empty() ? "" : "\n") + value;
  };
  const int shown = columns * per_column >= n ? n : std::max(0, columns * per_column - 1);
  for (int k = 0; k < shown; ++k) {
    if (k % per_column == 0) out.emplace_back();
    add(out.back(), rows[size_t(k)].first, rows[size_t(k)].second);
  }
  // mjr_overlay draws a row only with a value.
  if (shown < n) add(out.back(), "+" + std::to_string(n - shown), "more");
  return out;
}

std::vector<OffscreenRenderer::Overlay> OffscreenRenderer::fit_columns(const std::vector<Overlay>& columns) const {
  cut_rows_ = 0;
  if (columns.empty()) return {};
  const int cell = width_ / int(columns.size());
  std::vector<Overlay> out;
  for (const Overlay& c : columns) {
    std::vector<std::string> names, values;
    std::istringstream n(c.names), v(c.values);
    for (std::string a, b; std::getline(n, a) && std::getline(v, b);) {
      names.push_back(a);
      values.push_back(b);
    }
    int name_w = 0;
    for (const auto& a : names) name_w = std::max(name_w, text_width(a));
    // mjr_overlay sets the values off by about two characters after the widest name, with margins.
    const int fits = cell - name_w - 6 * context_.charWidth[int('x')];
    const int room = std::max(fits, 4 * context_.charWidth[int('x')]);
    Overlay f;
    auto row = [&](const std::string& a, const std::string& b) {
      f.names += (f.names.empty() ? "" : "\n") + (a.empty() ? std::string(" ") : a);
      f.values += (f.values.empty() ? "" : "\n") + b;
      if (text_width(b) > fits) ++cut_rows_;
    };
    for (size_t k = 0; k < names.size(); ++k) {
      // A value too wide for its cell goes on at its spaces, on rows of its own.
      std::istringstream words(values[k]);
      std::string line, word, name = names[k];
      while (words >> word) {
        if (!line.empty() && text_width(line + " " + word) > room) {
          row(name, line);
          name.clear();
          line.clear();
        }
        line += (line.empty() ? "" : " ") + word;
      }
      row(name, line);
    }
    out.push_back(f);
  }
  return out;
}

void OffscreenRenderer::render(mjvCamera& cam, const std::function<void(mjvScene&)>& decorate,
                               const std::vector<Overlay>& columns, unsigned char* rgb) {
  if (!have_context_) throw std::logic_error("OffscreenRenderer::render before set_model");
  mjv_updateScene(model_, data_, &option_, nullptr, &cam, mjCAT_ALL, &scene_);
  if (decorate) decorate(scene_);
  auto lines = [](const std::string& text) {
    return text.empty() ? 0 : 1 + int(std::count(text.begin(), text.end(), '\n'));
  };
  const std::vector<Overlay> fitted = fit_columns(columns);
  int rows = 0;
  for (const Overlay& c : fitted) rows = std::max(rows, lines(c.names));
  // The panel: mjr_overlay's rows (1.5 lines of the font each) and its margins, at most half the
  // frame (layout() keeps to that).
  const int panel = rows == 0 ? 0 : std::min(height_ / 2, (3 * rows + 2) * context_.charHeight / 2);
  mjr_setBuffer(mjFB_OFFSCREEN, &context_);
  const mjrRect frame{0, 0, width_, height_}, text{0, 0, width_, panel};
  mjr_rectangle(frame, 0, 0, 0, 1);
  scene_viewport_ = {0, panel, width_, height_ - panel};
  mjr_render(scene_viewport_, &scene_, &context_);
  if (rows > 0) {
    mjr_rectangle(text, kPanelGrey, kPanelGrey, kPanelGrey, 1);
    const int n = int(fitted.size());
    for (int i = 0; i < n; ++i) {
      if (fitted[i].names.empty()) continue;
      const mjrRect cell{i * width_ / n, 0, width_ / n, panel};
      mjr_overlay(mjFONT_NORMAL, mjGRID_TOPLEFT, cell, fitted[i].names.c_str(), fitted[i].values.c_str(), &context_);
    }
  }
  read_rgb(rgb);
}

OffscreenRenderer::Coverage OffscreenRenderer::coverage(const std::function<bool(int body)>& of_body) {
  if (!have_context_) throw std::logic_error("OffscreenRenderer::coverage before set_model");
  // The scene of the last render() twice, without shadows and reflections (which move with the
  // robot too): once whole, once without the bodies' geoms; what differs is what they cover.
  const mjrRect viewport = scene_viewport_;
  const mjtByte shadow = scene_.flags[mjRND_SHADOW], reflection = scene_.flags[mjRND_REFLECTION];
  scene_.flags[mjRND_SHADOW] = 0;
  scene_.flags[mjRND_REFLECTION] = 0;
  std::vector<unsigned char> with(rows_.size()), without(rows_.size());
  mjr_render(viewport, &scene_, &context_);
  read_rgb(with.data());
  const int ngeom = scene_.ngeom;
  const std::vector<mjvGeom> all(scene_.geoms, scene_.geoms + ngeom);
  int kept = 0;
  for (const mjvGeom& g : all)
    if (!(g.objtype == mjOBJ_GEOM && g.objid >= 0 && of_body(model_->geom_bodyid[g.objid]))) scene_.geoms[kept++] = g;
  scene_.ngeom = kept;
  mjr_render(viewport, &scene_, &context_);
  read_rgb(without.data());
  std::copy(all.begin(), all.end(), scene_.geoms);
  scene_.ngeom = ngeom;
  scene_.flags[mjRND_SHADOW] = shadow;
  scene_.flags[mjRND_REFLECTION] = reflection;
  size_t changed = 0;
  for (size_t p = 0; p < with.size(); p += 3) {
    bool differs = false;
    for (int c = 0; c < 3; ++c) differs = differs || std::abs(int(with[p + c]) - int(without[p + c])) > kPixelChange;
    changed += differs;
  }
  return {int64_t(changed), double(changed) / (double(viewport.width) * viewport.height)};
}

}  // namespace farm::tools
