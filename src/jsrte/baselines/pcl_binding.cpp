// A small pybind11 binding to PCL 1.13 (Debian's libpcl-dev): the exact implementations the paper
// used for its baselines. Built on first use by jsrte/baselines/pcl.py (see its docstring).
#include <pybind11/pybind11.h>
#include <pybind11/numpy.h>

#include <cmath>
#include <limits>

#include <pcl/features/our_cvfh.h>
#include <pcl/features/shot_omp.h>
#include <pcl/keypoints/harris_3d.h>
#include <pcl/console/print.h>
#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>

namespace py = pybind11;
using Floats = py::array_t<float, py::array::c_style | py::array::forcecast>;

namespace {

pcl::PointCloud<pcl::PointXYZ>::Ptr to_cloud(const Floats &a) {
  if (a.ndim() != 2 || a.shape(1) != 3) throw std::invalid_argument("points must be an (n, 3) array");
  auto r = a.unchecked<2>();
  pcl::PointCloud<pcl::PointXYZ>::Ptr c(new pcl::PointCloud<pcl::PointXYZ>);
  c->reserve(r.shape(0));
  for (py::ssize_t i = 0; i < r.shape(0); ++i) c->push_back(pcl::PointXYZ(r(i, 0), r(i, 1), r(i, 2)));
  return c;
}

pcl::PointCloud<pcl::Normal>::Ptr to_normals(const Floats &a) {
  if (a.ndim() != 2 || a.shape(1) != 3) throw std::invalid_argument("normals must be an (n, 3) array");
  auto r = a.unchecked<2>();
  pcl::PointCloud<pcl::Normal>::Ptr c(new pcl::PointCloud<pcl::Normal>);
  c->reserve(r.shape(0));
  for (py::ssize_t i = 0; i < r.shape(0); ++i) c->push_back(pcl::Normal(r(i, 0), r(i, 1), r(i, 2)));
  return c;
}

}  // namespace

// Harris 3D keypoints (method HARRIS, non-maximum suppression): positions (k, 3) and the
// indices (k,) of the cloud points they were detected at.
py::tuple harris3d(const Floats &points, const Floats &normals, float radius, float threshold, bool refine) {
  auto cloud = to_cloud(points);
  pcl::HarrisKeypoint3D<pcl::PointXYZ, pcl::PointXYZI, pcl::Normal> detector;
  detector.setInputCloud(cloud);
  detector.setNormals(to_normals(normals));
  detector.setRadius(radius);
  detector.setThreshold(threshold);
  detector.setNonMaxSupression(true);
  detector.setRefine(refine);
  pcl::PointCloud<pcl::PointXYZI> out;
  detector.compute(out);
  auto kept = detector.getKeypointsIndices();
  py::array_t<float> pos({static_cast<py::ssize_t>(out.size()), static_cast<py::ssize_t>(3)});
  py::array_t<long long> idx(static_cast<py::ssize_t>(out.size()));
  auto p = pos.mutable_unchecked<2>();
  auto q = idx.mutable_unchecked<1>();
  for (std::size_t i = 0; i < out.size(); ++i) {
    p(i, 0) = out[i].x; p(i, 1) = out[i].y; p(i, 2) = out[i].z;
    q(i) = (kept && i < kept->indices.size()) ? kept->indices[i] : -1;
  }
  return py::make_tuple(pos, idx);
}

// SHOT descriptors (k, 352) at keypoints, neighbourhoods taken from the surface cloud; a row of
// NaN where PCL could not compute one (too few neighbours for a local reference frame).
py::array_t<float> shot(const Floats &surface, const Floats &normals, const Floats &keypoints, float radius,
                        int threads) {
  pcl::SHOTEstimationOMP<pcl::PointXYZ, pcl::Normal, pcl::SHOT352> estimator(threads);
  estimator.setInputCloud(to_cloud(keypoints));
  estimator.setSearchSurface(to_cloud(surface));
  estimator.setInputNormals(to_normals(normals));
  estimator.setRadiusSearch(radius);
  pcl::PointCloud<pcl::SHOT352> out;
  estimator.compute(out);
  py::array_t<float> desc({static_cast<py::ssize_t>(out.size()), static_cast<py::ssize_t>(352)});
  auto d = desc.mutable_unchecked<2>();
  for (std::size_t i = 0; i < out.size(); ++i)
    for (int j = 0; j < 352; ++j) d(i, j) = out[i].descriptor[j];
  return desc;
}

// OUR-CVFH: one 308-bin signature per (smooth cluster, reference frame), the SGURF transforms
// (m, 4, 4) and whether each is valid (false: no smooth cluster, plain VFH with identity).
py::tuple ourcvfh(const Floats &points, const Floats &normals, float eps_angle, float curvature_threshold,
                  float cluster_tolerance, float radius_normals, int min_points, float axis_ratio,
                  float min_axis_value, bool normalize_bins, float refine_clusters) {
  auto cloud = to_cloud(points);
  pcl::OURCVFHEstimation<pcl::PointXYZ, pcl::Normal, pcl::VFHSignature308> estimator;
  estimator.setInputCloud(cloud);
  estimator.setInputNormals(to_normals(normals));
  estimator.setSearchMethod(pcl::search::KdTree<pcl::PointXYZ>::Ptr(new pcl::search::KdTree<pcl::PointXYZ>));
  estimator.setEPSAngleThreshold(eps_angle);
  estimator.setCurvatureThreshold(curvature_threshold);
  estimator.setClusterTolerance(cluster_tolerance);
  estimator.setRadiusNormals(radius_normals);
  estimator.setMinPoints(min_points);
  estimator.setAxisRatio(axis_ratio);
  estimator.setMinAxisValue(min_axis_value);
  estimator.setNormalizeBins(normalize_bins);
  estimator.setRefineClusters(refine_clusters);
  pcl::PointCloud<pcl::VFHSignature308> out;
  estimator.compute(out);
  std::vector<Eigen::Matrix4f, Eigen::aligned_allocator<Eigen::Matrix4f>> transforms;
  std::vector<bool> valid;
  estimator.getTransforms(transforms);
  estimator.getValidTransformsVec(valid);
  const auto m = static_cast<py::ssize_t>(out.size());
  py::array_t<float> desc({m, static_cast<py::ssize_t>(308)});
  py::array_t<float> frames({m, static_cast<py::ssize_t>(4), static_cast<py::ssize_t>(4)});
  py::array_t<bool> ok(m);
  auto d = desc.mutable_unchecked<2>();
  auto f = frames.mutable_unchecked<3>();
  auto v = ok.mutable_unchecked<1>();
  for (py::ssize_t i = 0; i < m; ++i) {
    for (int j = 0; j < 308; ++j) d(i, j) = out[i].histogram[j];
    const bool has = static_cast<std::size_t>(i) < transforms.size();
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) f(i, r, c) = has ? transforms[i](r, c) : (r == c ? 1.f : 0.f);
    v(i) = has && static_cast<std::size_t>(i) < valid.size() && valid[i];
  }
  return py::make_tuple(desc, frames, ok);
}

PYBIND11_MODULE(_jsrte_pcl, m) {
  m.doc() = "PCL 1.13 Harris3D, SHOT and OUR-CVFH for the jsrte baselines";
  pcl::console::setVerbosityLevel(pcl::console::L_ERROR);  // no per-point warnings on stderr
  m.def("harris3d", &harris3d, py::arg("points"), py::arg("normals"), py::arg("radius"), py::arg("threshold"),
        py::arg("refine"));
  m.def("shot", &shot, py::arg("surface"), py::arg("normals"), py::arg("keypoints"), py::arg("radius"),
        py::arg("threads") = 0);
  m.def("ourcvfh", &ourcvfh, py::arg("points"), py::arg("normals"), py::arg("eps_angle"),
        py::arg("curvature_threshold"), py::arg("cluster_tolerance"), py::arg("radius_normals"),
        py::arg("min_points"), py::arg("axis_ratio"), py::arg("min_axis_value"), py::arg("normalize_bins"),
        py::arg("refine_clusters"));
  m.attr("PCL_VERSION") = PCL_VERSION_PRETTY;
}
