// PCL peer for patchcloud's benchmarks: normals (k-NN or radius) and Difference of Normals, timed.
//
//   pcl_normals CLOUD.f64 OUT.f64 THREADS knn K VX VY VZ
//   pcl_normals CLOUD.f64 OUT.f64 THREADS radius R VX VY VZ
//   pcl_normals CLOUD.f64 OUT.f64 THREADS don R_SMALL R_LARGE VX VY VZ
//
// CLOUD.f64: N x 3 float64 (local frame, metres), row-major, no header.
// OUT.f64: N x 3 float64: the normals (knn, radius) or the DoN vectors (don), NaN where undefined.
// Prints one line: "seconds S" -- the k-d tree build plus the computation (NormalEstimationOMP with
// THREADS threads, normals flipped towards the viewpoint VX VY VZ; for don, both radii and
// pcl::DifferenceOfNormalsEstimation), reading and writing the files excluded.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

#include <pcl/common/io.h>
#include <pcl/features/don.h>
#include <pcl/features/normal_3d_omp.h>
#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>

using Cloud = pcl::PointCloud<pcl::PointXYZ>;
using Normals = pcl::PointCloud<pcl::PointNormal>;

static Normals::Ptr estimate(Cloud::ConstPtr cloud, pcl::search::KdTree<pcl::PointXYZ>::Ptr tree, int threads,
                             int k, double radius, float vx, float vy, float vz) {
  pcl::NormalEstimationOMP<pcl::PointXYZ, pcl::PointNormal> ne(threads);
  ne.setInputCloud(cloud);
  ne.setSearchMethod(tree);
  if (k > 0) ne.setKSearch(k); else ne.setRadiusSearch(radius);
  ne.setViewPoint(vx, vy, vz);
  Normals::Ptr out(new Normals);
  ne.compute(*out);
  return out;
}

int main(int argc, char** argv) {
  if (argc < 9) {
    std::fprintf(stderr, "usage: pcl_normals CLOUD OUT THREADS (knn K | radius R | don RS RL) VX VY VZ\n");
    return 2;
  }
  std::string mode = argv[4];
  int vp = mode == "don" ? 7 : 6;
  if (argc != vp + 3) { std::fprintf(stderr, "pcl_normals: wrong number of arguments\n"); return 2; }
  std::ifstream in(argv[1], std::ios::binary | std::ios::ate);
  if (!in) { std::fprintf(stderr, "pcl_normals: cannot read %s\n", argv[1]); return 2; }
  size_t bytes = in.tellg();
  size_t n = bytes / 24;
  std::vector<double> xyz(n * 3);
  in.seekg(0);
  in.read(reinterpret_cast<char*>(xyz.data()), n * 24);
  Cloud::Ptr cloud(new Cloud);
  cloud->resize(n);
  for (size_t i = 0; i < n; ++i) {
    (*cloud)[i].x = float(xyz[3 * i]); (*cloud)[i].y = float(xyz[3 * i + 1]); (*cloud)[i].z = float(xyz[3 * i + 2]);
  }
  int threads = std::atoi(argv[3]);
  float vx = std::atof(argv[vp]), vy = std::atof(argv[vp + 1]), vz = std::atof(argv[vp + 2]);
  std::vector<double> out(n * 3);
  auto t0 = std::chrono::steady_clock::now();
  pcl::search::KdTree<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>(false));
  tree->setInputCloud(cloud);
  if (mode == "don") {
    double rs = std::atof(argv[5]), rl = std::atof(argv[6]);
    Normals::Ptr small = estimate(cloud, tree, threads, 0, rs, vx, vy, vz);
    Normals::Ptr large = estimate(cloud, tree, threads, 0, rl, vx, vy, vz);
    pcl::DifferenceOfNormalsEstimation<pcl::PointXYZ, pcl::PointNormal, pcl::PointNormal> don;
    don.setInputCloud(cloud);
    don.setNormalScaleSmall(small);
    don.setNormalScaleLarge(large);
    Normals::Ptr result(new Normals);
    pcl::copyPointCloud(*cloud, *result);
    if (!don.initCompute()) { std::fprintf(stderr, "pcl_normals: DoN init failed\n"); return 1; }
    don.computeFeature(*result);
    auto t1 = std::chrono::steady_clock::now();
    for (size_t i = 0; i < n; ++i) {
      out[3 * i] = (*result)[i].normal_x; out[3 * i + 1] = (*result)[i].normal_y; out[3 * i + 2] = (*result)[i].normal_z;
    }
    std::printf("seconds %.6f\n", std::chrono::duration<double>(t1 - t0).count());
  } else {
    int k = mode == "knn" ? std::atoi(argv[5]) : 0;
    double r = mode == "radius" ? std::atof(argv[5]) : 0.0;
    if (mode != "knn" && mode != "radius") { std::fprintf(stderr, "pcl_normals: unknown mode %s\n", mode.c_str()); return 2; }
    Normals::Ptr nr = estimate(cloud, tree, threads, k, r, vx, vy, vz);
    auto t1 = std::chrono::steady_clock::now();
    for (size_t i = 0; i < n; ++i) {
      out[3 * i] = (*nr)[i].normal_x; out[3 * i + 1] = (*nr)[i].normal_y; out[3 * i + 2] = (*nr)[i].normal_z;
    }
    std::printf("seconds %.6f\n", std::chrono::duration<double>(t1 - t0).count());
  }
  std::ofstream o(argv[2], std::ios::binary);
  o.write(reinterpret_cast<const char*>(out.data()), n * 24);
  return o ? 0 : 1;
}
