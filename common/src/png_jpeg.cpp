#include "png_jpeg.hpp"

// libjpeg's header needs stdio's FILE and size_t first.
#include <cstdio>
#include <cstring>
#include <csetjmp>
#include <cstdlib>

#include <jpeglib.h>
#include <png.h>

#include "rekon/common/error.hpp"

namespace rekon::detail {
namespace {

// The functions that call setjmp hold no C++ object of their own: a libpng or
// libjpeg error returns to them by longjmp, and they report it with `false`.

struct PngMessage {
  char text[200] = "";
};

void pngFail(png_structp png, png_const_charp message) {
  auto* m = static_cast<PngMessage*>(png_get_error_ptr(png));
  std::snprintf(m->text, sizeof m->text, "%s", message);
  png_longjmp(png, 1);
}

void pngIgnoreWarning(png_structp, png_const_charp) {}

struct PngSource {
  const uint8_t* data;
  size_t size;
  size_t pos;
};

void pngReadMemory(png_structp png, png_bytep out, png_size_t n) {
  auto* s = static_cast<PngSource*>(png_get_io_ptr(png));
  if (n > s->size - s->pos) png_error(png, "the data ends early");
  std::memcpy(out, s->data + s->pos, n);
  s->pos += n;
}

struct PngReader {
  png_structp png = nullptr;
  png_infop info = nullptr;
  PngMessage message;
  PngSource source{};
  int bit_depth = 0, channels = 0;  // as stored
  png_uint_32 width = 0, height = 0;
  size_t rowbytes = 0;  // after the transformations
  PngReader(const uint8_t* data, size_t size) : source{data, size, 0} {
    png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &message, pngFail, pngIgnoreWarning);
    if (png) info = png_create_info_struct(png);
  }
  ~PngReader() { png_destroy_read_struct(&png, &info, nullptr); }
  PngReader(const PngReader&) = delete;
  PngReader& operator=(const PngReader&) = delete;
};

// The header, then the transformations to 16-bit grey in host order
// (`gray16`, applied only when the image is that) or to 8-bit BGR.
bool pngReadInfo(PngReader& r, bool gray16) {
  if (setjmp(png_jmpbuf(r.png))) return false;
  png_set_read_fn(r.png, &r.source, pngReadMemory);
  png_read_info(r.png, r.info);
  r.bit_depth = png_get_bit_depth(r.png, r.info);
  r.channels = png_get_channels(r.png, r.info);
  const int color_type = png_get_color_type(r.png, r.info);
  if (gray16) {
    if (r.bit_depth == 16 && color_type == PNG_COLOR_TYPE_GRAY) png_set_swap(r.png);
  } else {
    png_set_expand(r.png);
    png_set_strip_16(r.png);
    png_set_strip_alpha(r.png);
    png_set_gray_to_rgb(r.png);
    png_set_bgr(r.png);
  }
  png_set_interlace_handling(r.png);
  png_read_update_info(r.png, r.info);
  r.width = png_get_image_width(r.png, r.info);
  r.height = png_get_image_height(r.png, r.info);
  r.rowbytes = png_get_rowbytes(r.png, r.info);
  return true;
}

bool pngReadRows(PngReader& r, png_bytepp rows) {
  if (setjmp(png_jmpbuf(r.png))) return false;
  png_read_image(r.png, rows);
  png_read_end(r.png, nullptr);
  return true;
}

Error pngError(const std::string& what, const PngReader& r) {
  return Error(what + ": not a decodable PNG (" + r.message.text + "); replace the file");
}

void pngStart(PngReader& r, bool gray16, const std::string& what) {
  if (!r.info) throw Error(what + ": cannot start the PNG decoder (out of memory?)");
  if (!pngReadInfo(r, gray16)) throw pngError(what, r);
}

void pngReadInto(PngReader& r, cv::Mat& image, const std::string& what) {
  if (image.step[0] < r.rowbytes) throw pngError(what, r);
  std::vector<png_bytep> rows(static_cast<size_t>(image.rows));
  for (int y = 0; y < image.rows; ++y) rows[static_cast<size_t>(y)] = image.ptr<uint8_t>(y);
  if (!pngReadRows(r, rows.data())) throw pngError(what, r);
}

struct JpegFailure {
  jpeg_error_mgr manager;  // first: libjpeg's err pointer is this struct's
  std::jmp_buf jump;
  char text[JMSG_LENGTH_MAX];
};

void jpegFail(j_common_ptr c) {
  auto* f = reinterpret_cast<JpegFailure*>(c->err);
  (*c->err->format_message)(c, f->text);
  std::longjmp(f->jump, 1);
}

void jpegIgnoreMessage(j_common_ptr) {}

// The error manager to give a (de)compressor: errors return by longjmp to
// f.jump with their text, warnings are dropped.
jpeg_error_mgr* jpegErrors(JpegFailure& f) {
  jpeg_std_error(&f.manager);
  f.manager.error_exit = jpegFail;
  f.manager.output_message = jpegIgnoreMessage;
  return &f.manager;
}

Error jpegError(const std::string& what, const JpegFailure& f) {
  return Error(what + ": not a decodable JPEG (" + f.text + "); replace the file");
}

bool jpegStart(jpeg_decompress_struct& d, JpegFailure& f, const uint8_t* data, size_t size) {
  if (setjmp(f.jump)) return false;
  jpeg_mem_src(&d, data, static_cast<unsigned long>(size));
  jpeg_read_header(&d, TRUE);
  d.out_color_space = JCS_EXT_BGR;
  jpeg_start_decompress(&d);
  return true;
}

bool jpegReadRows(jpeg_decompress_struct& d, JpegFailure& f, uint8_t* out, size_t step) {
  if (setjmp(f.jump)) return false;
  while (d.output_scanline < d.output_height) {
    JSAMPROW row = out + step * d.output_scanline;
    jpeg_read_scanlines(&d, &row, 1);
  }
  jpeg_finish_decompress(&d);
  return true;
}

void pngWriteMemory(png_structp png, png_bytep data, png_size_t n) {
  auto* out = static_cast<std::vector<uint8_t>*>(png_get_io_ptr(png));
  out->insert(out->end(), data, data + n);
}

void pngFlushNothing(png_structp) {}

bool pngWrite(png_structp png, png_infop info, std::vector<uint8_t>* out, png_uint_32 width, png_uint_32 height,
              int bit_depth, int color_type, int level, png_bytepp rows) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_set_write_fn(png, out, pngWriteMemory, pngFlushNothing);
  png_set_IHDR(png, info, width, height, bit_depth, color_type, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_set_compression_level(png, level);
  png_set_filter(png, PNG_FILTER_TYPE_BASE, PNG_FILTER_SUB);  // one cheap filter: frames are encoded per publish
  png_write_info(png, info);
  if (color_type == PNG_COLOR_TYPE_RGB || color_type == PNG_COLOR_TYPE_RGB_ALPHA) png_set_bgr(png);
  if (bit_depth == 16) png_set_swap(png);
  png_write_image(png, rows);
  png_write_end(png, nullptr);
  return true;
}

bool jpegWrite(jpeg_compress_struct& c, JpegFailure& f, const cv::Mat& image, int quality, unsigned char** buffer,
               unsigned long* size) {
  if (setjmp(f.jump)) return false;
  jpeg_mem_dest(&c, buffer, size);
  c.image_width = static_cast<JDIMENSION>(image.cols);
  c.image_height = static_cast<JDIMENSION>(image.rows);
  c.input_components = image.channels();
  c.in_color_space = image.channels() == 1 ? JCS_GRAYSCALE : JCS_EXT_BGR;
  jpeg_set_defaults(&c);
  jpeg_set_quality(&c, quality, TRUE);
  jpeg_start_compress(&c, TRUE);
  while (c.next_scanline < c.image_height) {
    JSAMPROW row = const_cast<uint8_t*>(image.ptr<uint8_t>(static_cast<int>(c.next_scanline)));
    jpeg_write_scanlines(&c, &row, 1);
  }
  jpeg_finish_compress(&c);
  return true;
}

}  // namespace

cv::Mat decodePngGray16(const uint8_t* data, size_t size, const std::string& what) {
  PngReader r(data, size);
  pngStart(r, true, what);
  if (r.bit_depth != 16 || r.channels != 1) {
    throw Error(what + ": depth must be a 16-bit single-channel PNG, found " + std::to_string(r.bit_depth) +
                "-bit with " + std::to_string(r.channels) + " channel(s); convert the depth image");
  }
  cv::Mat image(static_cast<int>(r.height), static_cast<int>(r.width), CV_16UC1);
  pngReadInto(r, image, what);
  return image;
}

cv::Mat decodePngBgr(const uint8_t* data, size_t size, const std::string& what) {
  PngReader r(data, size);
  pngStart(r, false, what);
  cv::Mat image(static_cast<int>(r.height), static_cast<int>(r.width), CV_8UC3);
  pngReadInto(r, image, what);
  return image;
}

cv::Mat decodeJpegBgr(const uint8_t* data, size_t size, const std::string& what) {
  jpeg_decompress_struct d{};
  JpegFailure f{};
  d.err = jpegErrors(f);
  jpeg_create_decompress(&d);
  struct Destroy {
    jpeg_decompress_struct& d;
    ~Destroy() { jpeg_destroy_decompress(&d); }
  } destroy{d};
  if (!jpegStart(d, f, data, size)) throw jpegError(what, f);
  if (d.output_components != 3) throw Error(what + ": color must be 8-bit; convert the color image");
  cv::Mat image(static_cast<int>(d.output_height), static_cast<int>(d.output_width), CV_8UC3);
  if (!jpegReadRows(d, f, image.data, image.step[0])) throw jpegError(what, f);
  return image;
}

std::vector<uint8_t> encodePngImage(const cv::Mat& image, int level) {
  int color_type = 0, bit_depth = 8;
  switch (image.type()) {
    case CV_8UC1: color_type = PNG_COLOR_TYPE_GRAY; break;
    case CV_16UC1: color_type = PNG_COLOR_TYPE_GRAY, bit_depth = 16; break;
    case CV_8UC3: color_type = PNG_COLOR_TYPE_RGB; break;
    case CV_8UC4: color_type = PNG_COLOR_TYPE_RGB_ALPHA; break;
    default: throw Error("PNG encoding: only 8-bit grey, BGR or BGRA and 16-bit grey images are written");
  }
  PngMessage message;
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &message, pngFail, pngIgnoreWarning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  struct Destroy {
    png_structp& png;
    png_infop& info;
    ~Destroy() { png_destroy_write_struct(&png, &info); }
  } destroy{png, info};
  if (!info) throw Error("PNG encoding failed: cannot start the encoder (out of memory?)");
  std::vector<png_bytep> rows(static_cast<size_t>(image.rows));
  for (int y = 0; y < image.rows; ++y) rows[static_cast<size_t>(y)] = const_cast<uint8_t*>(image.ptr<uint8_t>(y));
  std::vector<uint8_t> out;
  if (!pngWrite(png, info, &out, static_cast<png_uint_32>(image.cols), static_cast<png_uint_32>(image.rows), bit_depth,
                color_type, level, rows.data()))
    throw Error(std::string("PNG encoding failed: ") + message.text);
  return out;
}

std::vector<uint8_t> encodeJpegImage(const cv::Mat& image, int quality) {
  if (image.type() != CV_8UC1 && image.type() != CV_8UC3) throw Error("JPEG encoding: only 8-bit grey or BGR images");
  jpeg_compress_struct c{};
  JpegFailure f{};
  c.err = jpegErrors(f);
  jpeg_create_compress(&c);
  unsigned char* buffer = nullptr;
  unsigned long size = 0;
  struct Destroy {
    jpeg_compress_struct& c;
    unsigned char*& buffer;
    ~Destroy() {
      jpeg_destroy_compress(&c);
      std::free(buffer);
    }
  } destroy{c, buffer};
  if (!jpegWrite(c, f, image, quality, &buffer, &size)) throw Error(std::string("JPEG encoding failed: ") + f.text);
  return std::vector<uint8_t>(buffer, buffer + size);
}

}  // namespace rekon::detail
