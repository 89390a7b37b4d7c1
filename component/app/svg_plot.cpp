#include "svg_plot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

namespace ve::app {

namespace {

std::string escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

/// A "nice" tick step (1, 2 or 5 times a power of ten) for about `target` ticks over span.
double tick_step(double span, int target) {
  if (!(span > 0.0)) return 1.0;
  const double raw = span / target;
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  const double f = raw / mag;
  return (f < 1.5 ? 1.0 : f < 3.5 ? 2.0 : f < 7.5 ? 5.0 : 10.0) * mag;
}

std::string num(double v, double step) {
  char buf[64];
  const int decimals = step >= 1.0 ? 0 : std::min(9, static_cast<int>(std::ceil(-std::log10(step) - 1e-9)));
  std::snprintf(buf, sizeof buf, "%.*f", decimals, std::abs(v) < 1e-12 * step ? 0.0 : v);
  return buf;
}

}  // namespace

const char* svg_color(int i) {
  static const char* kPalette[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e",
                                   "#9467bd", "#8c564b", "#e377c2", "#17becf"};
  return kPalette[static_cast<unsigned>(i) % 8u];
}

std::string render_svg(const SvgPlot& p) {
  // Data range over every finite point and marker line.
  double x0 = std::numeric_limits<double>::infinity(), x1 = -x0, y0 = x0, y1 = -x0;
  for (const auto& s : p.series)
    for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
      x0 = std::min(x0, s.x[i]);
      x1 = std::max(x1, s.x[i]);
      y0 = std::min(y0, s.y[i]);
      y1 = std::max(y1, s.y[i]);
    }
  for (const auto& h : p.hlines)
    if (std::isfinite(h.first)) {
      y0 = std::min(y0, h.first);
      y1 = std::max(y1, h.first);
    }
  if (!(x1 >= x0)) x0 = 0.0, x1 = 1.0;
  if (!(y1 >= y0)) y0 = 0.0, y1 = 1.0;
  if (x1 - x0 <= 0.0) x0 -= 0.5, x1 += 0.5;
  if (y1 - y0 <= 0.0) {
    const double d = std::max(1e-9, std::abs(y0) * 0.1);
    y0 -= d, y1 += d;
  }
  const double xs = tick_step(x1 - x0, 8), ys = tick_step(y1 - y0, 6);
  // Widen y to whole ticks with a little air; x to whole ticks only when close.
  y0 = std::floor(y0 / ys) * ys;
  y1 = std::ceil(y1 / ys) * ys;

  const double W = p.width_px, H = p.height_px;
  const double left = 80, right = 20, top = 40, bottom = 60;
  const double pw = W - left - right, ph = H - top - bottom;
  auto X = [&](double x) { return left + (x - x0) / (x1 - x0) * pw; };
  auto Y = [&](double y) { return top + (y1 - y) / (y1 - y0) * ph; };

  std::string out;
  char buf[512];
  auto put = [&](const char* format, auto... args) {
    std::snprintf(buf, sizeof buf, format, args...);
    out += buf;
  };
  put("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
  put("<svg xmlns=\"http://www.w3.org/2000/svg\" version=\"1.1\" width=\"%d\" height=\"%d\" viewBox=\"0 0 %d %d\" "
      "font-family=\"sans-serif\" font-size=\"12\">\n",
      p.width_px, p.height_px, p.width_px, p.height_px);
  out += "<title>" + escape(p.title) + "</title>\n";
  put("<rect x=\"0\" y=\"0\" width=\"%d\" height=\"%d\" fill=\"white\"/>\n", p.width_px, p.height_px);
  out += "<text x=\"" + std::to_string(static_cast<int>(W / 2)) +
         "\" y=\"22\" text-anchor=\"middle\" font-size=\"15\" font-weight=\"bold\">" + escape(p.title) + "</text>\n";

  // Grid and ticks.
  out += "<g stroke=\"#dddddd\" stroke-width=\"1\">\n";
  for (double t = std::ceil(x0 / xs) * xs; t <= x1 + 1e-9 * xs; t += xs) put("<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\"/>\n", X(t), top, X(t), top + ph);
  for (double t = y0; t <= y1 + 1e-9 * ys; t += ys) put("<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\"/>\n", left, Y(t), left + pw, Y(t));
  out += "</g>\n<g fill=\"#333333\">\n";
  for (double t = std::ceil(x0 / xs) * xs; t <= x1 + 1e-9 * xs; t += xs)
    put("<text x=\"%.1f\" y=\"%.1f\" text-anchor=\"middle\">%s</text>\n", X(t), top + ph + 16, num(t, xs).c_str());
  for (double t = y0; t <= y1 + 1e-9 * ys; t += ys)
    put("<text x=\"%.1f\" y=\"%.1f\" text-anchor=\"end\">%s</text>\n", left - 6, Y(t) + 4, num(t, ys).c_str());
  out += "</g>\n";
  put("<rect x=\"%.1f\" y=\"%.1f\" width=\"%.1f\" height=\"%.1f\" fill=\"none\" stroke=\"#333333\"/>\n", left, top, pw, ph);
  out += "<text x=\"" + std::to_string(static_cast<int>(left + pw / 2)) + "\" y=\"" +
         std::to_string(static_cast<int>(H - 18)) + "\" text-anchor=\"middle\">" + escape(p.x_label) + "</text>\n";
  put("<text x=\"18\" y=\"%.1f\" text-anchor=\"middle\" transform=\"rotate(-90 18 %.1f)\">", top + ph / 2, top + ph / 2);
  out += escape(p.y_label) + "</text>\n";

  // Marker lines.
  for (const auto& h : p.hlines) {
    if (!std::isfinite(h.first)) continue;
    put("<line x1=\"%.1f\" y1=\"%.2f\" x2=\"%.1f\" y2=\"%.2f\" stroke=\"#555555\" stroke-dasharray=\"6 4\"/>\n", left,
        Y(h.first), left + pw, Y(h.first));
    put("<text x=\"%.1f\" y=\"%.2f\" text-anchor=\"end\" fill=\"#555555\">", left + pw - 4, Y(h.first) - 4);
    out += escape(h.second) + "</text>\n";
  }

  // Series, clipped to the plot area.
  put("<clipPath id=\"area\"><rect x=\"%.1f\" y=\"%.1f\" width=\"%.1f\" height=\"%.1f\"/></clipPath>\n", left, top, pw, ph);
  out += "<g clip-path=\"url(#area)\" fill=\"none\" stroke-linejoin=\"round\">\n";
  for (const auto& s : p.series) {
    std::string points;
    auto flush = [&]() {
      if (points.empty()) return;
      put("<polyline stroke=\"%s\" stroke-width=\"%.2f\" stroke-opacity=\"%.3f\" points=\"", s.color.c_str(), s.width,
          s.opacity);
      out += points + "\"/>\n";
      points.clear();
    };
    for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) {
        flush();
        continue;
      }
      std::snprintf(buf, sizeof buf, "%s%.2f,%.2f", points.empty() ? "" : " ", X(s.x[i]), Y(s.y[i]));
      points += buf;
    }
    flush();
  }
  out += "</g>\n";

  // Legend, top right inside the plot.
  int row = 0;
  for (const auto& s : p.series) {
    if (s.label.empty()) continue;
    const double ly = top + 14 + 16 * row++;
    put("<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"%s\" stroke-width=\"3\"/>\n", left + pw - 150,
        ly - 4, left + pw - 130, ly - 4, s.color.c_str());
    put("<text x=\"%.1f\" y=\"%.1f\">", left + pw - 124, ly);
    out += escape(s.label) + "</text>\n";
  }
  out += "</svg>\n";
  return out;
}

}  // namespace ve::app
