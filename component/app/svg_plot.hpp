// A minimal line-plot writer for the calibration report: axes with 1-2-5 ticks,
// polylines (NaN breaks a line), horizontal marker lines, a legend. Plain SVG 1.1
// text, no dependency; a browser or any image viewer shows it.
#pragma once

#include <string>
#include <vector>

namespace ve::app {

struct SvgSeries {
  std::string label;          ///< legend text; empty: not in the legend
  std::string color = "#1f77b4";
  std::vector<double> x, y;   ///< same length; a NaN in y breaks the line
  double width = 1.3;         ///< stroke width [px]
  double opacity = 1.0;
};

struct SvgPlot {
  std::string title;
  std::string x_label;
  std::string y_label;
  std::vector<SvgSeries> series;
  /// Dashed horizontal lines at these y values, with their labels.
  std::vector<std::pair<double, std::string>> hlines;
  int width_px = 960;
  int height_px = 520;
};

/// The plot as a complete SVG document.
std::string render_svg(const SvgPlot& plot);

/// Colour for series number i (a fixed palette that repeats).
const char* svg_color(int i);

}  // namespace ve::app
